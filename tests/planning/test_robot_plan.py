"""`riskplan plan robot`: the lab's task file to a checked plan (tiny preset), the model cache
(a second run rebuilds nothing), `--model`, inputs refused before any work; the planning
coordinates and walls of `riskplan.planning.robot_plan`."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import NumpyMixture
from riskplan.planning.prm import MeanValidity
from riskplan.planning.problem import load_problem
from riskplan.planning.problem_scene import WallEnvironment, problem_configurations
from riskplan.planning.robot_plan import configuration_weights
from tests.conftest import TOL

LAB = Path(__file__).resolve().parents[1] / "data" / "kuntz-lab"
TASK = LAB / "task-0001.toml"
STL = "collapse-segmentation-reoriented-with-hole-3k.stl"
FAST = ["--preset", "tiny", "--milestones", "15", "--iterations", "1"]

runner = CliRunner()


def _plan(*args):
    return runner.invoke(app, ["plan", "robot", *args])


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """One end-to-end run from an empty cache, then the same command again."""
    root = tmp_path_factory.mktemp("planrobot")
    cache = root / "cache"
    first = _plan("--problem", str(TASK), "--cache", str(cache), "--out", str(root / "a"), *FAST)
    assert first.exit_code == 0, first.output
    (build_json,) = cache.glob("*/*/build.json")
    stamp = {p: p.stat().st_mtime_ns for p in build_json.parent.rglob("*") if p.is_file()}
    second = _plan("--problem", str(TASK), "--cache", str(cache), "--out", str(root / "b"), *FAST)
    assert second.exit_code == 0, second.output
    return root, cache, build_json, stamp


def test_lab_task_to_an_exported_checked_plan(built):
    from riskplan.planning.export import read_tendon_plan

    root, _cache, build_json, _ = built
    out = root / "a"
    summary = json.loads((out / "plan.json").read_text())
    assert summary["model"]["cached"] is False
    assert set(summary["model"]["build_timings_s"]) == {"dataset_s", "training_s", "evaluation_s"}
    assert np.isfinite(summary["model"]["evaluation"]["test_nll"])
    # the cache folder is named by the robot's content hash
    assert build_json.parent.parent.name == json.loads(build_json.read_text())["robot_hash"]
    # the trajectory starts and ends at the task's start and goal (displacement form)
    start, goal = problem_configurations(load_problem(TASK))
    nominal = np.array(json.loads((out / "nominal.json").read_text())["configurations"])
    np.testing.assert_allclose(nominal[0], start, **TOL["float64_exact"])
    np.testing.assert_allclose(nominal[-1], goal, **TOL["float64_exact"])
    header = (out / "nominal.csv").read_text().splitlines()[1]
    assert header.endswith("rotation_rad,retraction_m,bound_eq9")
    # exported for a controller: tendon joints, tensions at each configuration's retraction
    plan = read_tendon_plan(out / "optimised_plan.joint_trajectory.yaml")
    assert plan.displacements.shape == (len(nominal), 3)
    np.testing.assert_allclose(
        plan.tensions[-1], load_problem(TASK).goal[:3], **TOL["tension_solve"]
    )
    # base rotation and retraction are the joints after the tendons, positions as planned
    nom = read_tendon_plan(out / "nominal_plan.joint_trajectory.yaml")
    np.testing.assert_array_equal(nom.displacements, nominal[:, :3])
    np.testing.assert_array_equal(nom.rotation, nominal[:, 3])
    np.testing.assert_array_equal(nom.retraction, nominal[:, 4])
    # checked on the robot model; no paper framing, no chest file names
    check = summary["robot_model_check"]
    assert set(check) == {"nominal", "optimised"}
    assert check["nominal"]["configurations"] == len(nominal)
    assert (out / "scene.html").is_file() and not (out / "chest.html").exists()
    assert "paper" not in json.loads((out / "trace.json").read_text())


def test_second_run_uses_the_cache(built):
    root, _cache, _build_json, stamp = built
    summary = json.loads((root / "b" / "plan.json").read_text())
    assert summary["model"]["cached"] is True and summary["model"]["build_timings_s"] == {}
    assert {p: p.stat().st_mtime_ns for p in stamp} == stamp  # nothing rewritten
    a = json.loads((root / "a" / "optimised.json").read_text())["configurations"]
    b = json.loads((root / "b" / "optimised.json").read_text())["configurations"]
    np.testing.assert_array_equal(a, b)


def test_given_model_is_used_and_nothing_is_built(built, tmp_path):
    _root, _, build_json, _ = built
    fresh = tmp_path / "cache"
    r = _plan(
        "--problem", str(TASK), "--model", str(build_json.parent / "model"),
        "--cache", str(fresh), "--out", str(tmp_path / "o"), *FAST,
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "o" / "plan.json").read_text())["model"] is None
    assert not fresh.exists()


def test_executions_validate_a_base_motion_plan(built, tmp_path):
    """`--executions N`: both trajectories (tendons, rotation, retraction) executed N times on
    the simulated robot with the base as commanded, the tube body only (the disks sit at the
    unretracted arc lengths); written as the chest plan writes its validation."""
    _root, _, build_json, _ = built
    out = tmp_path / "v"
    r = _plan(
        "--problem", str(TASK), "--model", str(build_json.parent / "model"),
        "--out", str(out), "--executions", "12", "--mixture-samples", "200", *FAST,
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    rows = json.loads((out / "validation.json").read_text())["rows"]
    assert [row["name"] for row in rows] == ["nominal", "optimised"]
    nominal = np.array(json.loads((out / "nominal.json").read_text())["configurations"])
    for row in rows:
        assert row["n_robot"] == 12 and 0 <= row["robot_hits"] <= 12
        assert row["robot_disks_mc"] is None
        assert row["robot_low"] <= row["robot_mc"] <= row["robot_high"]
    assert rows[0]["T"] == len(nominal) and len(rows[0]["robot_per_config"]) == len(nominal)
    assert "retracting base: tube only" in (out / "validation.md").read_text()


def _task_copy(tmp_path, old=None, new=None, mesh_scale=1.0):
    import trimesh

    text = TASK.read_text()
    if old is not None:
        assert old in text
        text = text.replace(old, new)
    m = trimesh.load(LAB / STL)
    m.apply_scale(mesh_scale)
    m.export(tmp_path / STL)
    shutil.copy(LAB / "collapse-segmentation-moved-with-hole.msgpack", tmp_path)
    (tmp_path / "task.toml").write_text(text)
    return tmp_path / "task.toml"


@pytest.mark.parametrize(
    "edit, match",
    [
        (dict(old="goal = [ 1.0712,", new="goal = [ 4.0,"), r"problem\.goal\[0\].*max_tension"),
        (dict(mesh_scale=1000.0), r"environment\.meshes\[0\]\.filename.*millimetres"),
        (
            dict(old="goal_retraction = 0.0267231", new="goal_retraction = 0.5"),
            r"problem\.goal_retraction.*outside the limits",
        ),
    ],
)
def test_bad_problem_refused_before_any_work(tmp_path, edit, match):
    task = _task_copy(tmp_path, **edit)
    cache, out = tmp_path / "cache", tmp_path / "out"
    r = _plan("--problem", str(task), "--cache", str(cache), "--out", str(out), *FAST)
    assert isinstance(r.exception, InvalidInputError), r.output
    assert __import__("re").search(match, str(r.exception)), str(r.exception)
    assert not cache.exists() and not out.exists()


def test_bad_options_refused_before_any_work(tmp_path):
    cache, out = tmp_path / "cache", tmp_path / "out"
    common = ["--cache", str(cache), "--out", str(out), *FAST]
    cases = [
        (["--robot", str(TASK), "--env", str(LAB / STL), "--start", "0,0,0,0,0.119"], "--goal"),
        (
            [
                "--robot",
                str(TASK),
                "--env",
                str(LAB / STL),
                "--start",
                "0,0,9,0,0.119",
                "--goal",
                "0,0,0,0,0.1",
            ],
            "--start",
        ),
        (
            [
                "--robot",
                str(TASK),
                "--env",
                str(tmp_path / "no.stl"),
                "--start",
                "0,0,0,0,0.119",
                "--goal",
                "0,0,0,0,0.1",
            ],
            "--env",
        ),
        (["--problem", str(TASK), "--model", "paper"], "--model"),
        (["--problem", str(TASK), "--goal", "1,1,1,0,0.1"], "--problem"),
    ]
    for args, name in cases:
        r = _plan(*args, *common)
        assert isinstance(r.exception, InvalidInputError), (args, r.output)
        assert name in str(r.exception)
        assert not cache.exists() and not out.exists()


def test_planning_weights_scale_rotation_by_the_robot_length():
    robot = load_problem(TASK).robot
    w = configuration_weights(robot, robot.n_config)
    np.testing.assert_array_equal(w, [1.0, 1.0, 1.0, robot.params.backbone.length, 1.0])
    from riskplan.robots import load_robot

    paper = load_robot("paper")
    np.testing.assert_array_equal(configuration_weights(paper, paper.n_config), np.ones(4))


class _LineModel:
    """A 1-input model whose one component mean sits at ``(x, 0, 0)``."""

    limits = np.array([[0.0, 1.0]])

    def predict(self, x):
        x = np.asarray(x, dtype=np.float64).reshape(-1, 1)
        mu = np.concatenate([x, np.zeros((len(x), 2))], axis=1)[:, None, :]
        u = np.broadcast_to(np.eye(3) * 100.0, (len(x), 1, 3, 3))
        return NumpyMixture(np.ones((len(x), 1)), mu, u)


def test_a_motion_whose_means_cross_a_wall_is_invalid():
    # an open square (two triangles) at x = 0.5: a wall, no inside
    V = np.array([[0.5, -1, -1], [0.5, 1, -1], [0.5, 1, 1], [0.5, -1, 1]], dtype=np.float64)
    wall = WallEnvironment(V, np.array([[0, 1, 2], [0, 2, 3]]))
    v = MeanValidity(_LineModel(), wall)
    assert v(np.array([[0.2], [0.8]])).all()  # either side of a wall is free
    ok = v.motions(np.array([[0.2], [0.2], [0.8]]), np.array([[0.4], [0.8], [0.6]]), 0.05)
    np.testing.assert_array_equal(ok, [True, False, True])


def test_a_killed_build_continues_where_it_stopped(built, tmp_path):
    """A build killed after training (no test split, no build.json): the next call generates
    only what is missing, trains nothing, and gives the same model."""
    import torch

    from riskplan.kinematics.model_cache import ensure_model

    _, cache, build_json, _ = built
    folder = build_json.parent
    robot = load_problem(TASK).robot
    before = ensure_model(robot, preset="tiny", cache=cache)
    assert before.cached
    copy = tmp_path / "cache"
    shutil.copytree(folder.parent, copy / folder.parent.name)
    killed = copy / folder.parent.name / folder.name
    for name in ("build.json", "evaluation.json", "data_test.h5", "model/trained.json"):
        (killed / name).unlink()
    train_stamp = (killed / "data_train.h5").stat().st_mtime_ns
    weights_stamp = (killed / "model" / "weights.pt").stat().st_mtime_ns
    stages = []
    after = ensure_model(
        robot, preset="tiny", cache=copy, progress=lambda s, d, n: stages.append(s)
    )
    assert not after.cached and (killed / "build.json").is_file()
    assert (killed / "data_train.h5").stat().st_mtime_ns == train_stamp  # kept
    assert (killed / "model" / "weights.pt").stat().st_mtime_ns == weights_stamp  # not retrained
    assert (killed / "data_test.h5").is_file()
    for a, b in zip(before.model.net.parameters(), after.model.net.parameters()):
        assert torch.equal(a, b)
    assert after.evaluation["test_nll"] == before.evaluation["test_nll"]
