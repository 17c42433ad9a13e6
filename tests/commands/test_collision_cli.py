"""CLI smoke tests for `riskplan env chest`, `riskplan collision`, `riskplan collision-table`."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.collision import Environment
from tests.conftest import TOL

runner = CliRunner()


def test_env_chest(tmp_path):
    out = tmp_path / "chest.stl"
    res = runner.invoke(
        app,
        [
            "env",
            "chest",
            "--out",
            str(out),
            "--subdivisions",
            "2",
            "--view",
            str(tmp_path / "c.png"),
        ],
    )
    assert res.exit_code == 0, res.output
    env = Environment.load(out)
    meta = json.loads((tmp_path / "chest.stl.json").read_text())
    assert env.n_faces == meta["triangles"]
    assert (tmp_path / "c.png").stat().st_size > 1000


def test_collision_arc_json():
    res = runner.invoke(
        app, ["collision", "probability", "--arc", "8,0", "--samples", "2000", "--json"]
    )
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)
    assert rows[0]["probability"] >= rows[0]["mc_low"]


def test_collision_union_reference_estimates_the_union_event():
    # the reference column must estimate what the method bounds: for the union methods the
    # event "any of K points, one per component, collides", not "a mixture point collides"
    def rows(method):
        res = runner.invoke(
            app,
            [
                "collision",
                "probability",
                "--arc",
                "8,0",
                "--samples",
                "2000",
                "--method",
                method,
                "--json",
            ],
        )
        assert res.exit_code == 0, res.output
        return json.loads(res.output)[0]

    mc_union, union, weighted = rows("monte_carlo_union"), rows("union"), rows("monte_carlo")
    assert mc_union["monte_carlo"] == mc_union["probability"]  # same samples, same seed
    assert union["monte_carlo"] == mc_union["probability"]
    assert union["probability"] >= union["mc_low"]
    assert weighted["monte_carlo"] == weighted["probability"]


def test_collision_requires_configuration():
    res = runner.invoke(app, ["collision", "probability"])
    assert res.exit_code != 0


def test_collision_robot_configurations():
    res = runner.invoke(
        app, ["collision", "probability", "-d", "0,0,0,0;0.02,0,0,0", "--samples", "2000", "--json"]
    )
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)
    assert len(rows) == 2 and rows[1]["probability"] > rows[0]["probability"]
    assert all(r["probability"] >= r["mc_low"] for r in rows)


def test_env_file_gives_the_built_in_chest_answer(tmp_path):
    # `env chest` writes the mesh in the world frame; its sidecar carries the robot base pose, so
    # the file and the built-in chest give the same bound (it was 0.61 against 0.0068 when the
    # world-frame file was read as base frame). STL stores float32: agreement to ~1e-5.
    rel = TOL["float32_mesh_probability"]["rtol"]
    out = tmp_path / "chest.stl"
    assert runner.invoke(app, ["env", "chest", "--out", str(out)]).exit_code == 0
    args = ["collision", "probability", "-d", "0,0,0,0;0.02,0,0,0", "--samples", "200", "--json"]
    built_in = json.loads(runner.invoke(app, args).output)
    from_file = json.loads(runner.invoke(app, args + ["--env", str(out)]).output)
    for a, b in zip(built_in, from_file):
        assert abs(a["probability"] - b["probability"]) <= rel * max(a["probability"], 1e-3)
    # a mesh without its sidecar has no known frame: a clear error, not a silent guess
    bare = tmp_path / "bare.stl"
    bare.write_bytes(out.read_bytes())
    res = runner.invoke(app, args + ["--env", str(bare)])
    assert res.exit_code != 0 and "frame is unknown" in str(res.exception)
    # ... unless the pose is given
    pose = tmp_path / "chest.stl.json"
    res = runner.invoke(app, args + ["--env", str(bare), "--base-pose", str(pose)])
    assert res.exit_code == 0, res.output
    assert abs(json.loads(res.output)[0]["probability"] - built_in[0]["probability"]) <= rel * max(
        built_in[0]["probability"], 1e-3
    )


def test_collision_env_in_millimetres_is_refused(tmp_path):
    """A mesh in millimetres (a 0.2 m box written as 200 units) is judged against the robot's
    length and refused, naming the option and the units; the same mesh in metres is accepted."""
    import trimesh

    from riskplan.errors import InvalidInputError

    box = trimesh.creation.box(extents=[0.2, 0.2, 0.2])
    box.apply_translation([0.3, 0.0, 0.1])
    box.export(tmp_path / "m.stl")
    box.apply_scale(1000.0)
    box.export(tmp_path / "mm.stl")
    args = [
        "collision",
        "probability",
        "--arc",
        "8,0",
        "--samples",
        "200",
        "--base-pose",
        "0,0,0,1,0,0,0",
    ]
    res = runner.invoke(app, [*args, "--env", str(tmp_path / "mm.stl"), "--json"])
    assert isinstance(res.exception, InvalidInputError), res.output
    msg = str(res.exception)
    assert "--env" in msg and "mm.stl" in msg
    assert "times the robot's length" in msg and "millimetres" in msg
    res = runner.invoke(app, [*args, "--env", str(tmp_path / "m.stl"), "--json"])
    assert res.exit_code == 0, res.output
