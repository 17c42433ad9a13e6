"""CLI smoke test of `riskplan plan chest` on a tiny problem, and its named errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.errors import DataFormatError, InvalidInputError, PlanningError
from tests.conftest import TOL, approx_tol

runner = CliRunner()


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """An (untrained, seeded) two-tendon MDN saved as a model folder, and a box mesh in world
    coordinates with a base pose placing the robot below it."""
    import trimesh

    from riskplan.kinematics import MDN, MDNModel, Normalisation, save_model

    root = tmp_path_factory.mktemp("tiny")
    torch.manual_seed(0)
    net = MDN(2, 2, hidden=(8,), head_hidden=()).double()
    norm = Normalisation(
        np.full(2, 0.015),
        np.full(2, 0.015),
        np.array([0.0, 0.0, 0.1]),
        np.array([0.02, 0.02, 0.02]),
    )
    model = MDNModel(net, norm, np.array([[-0.01, 0.04], [-0.01, 0.04]]), robot_name="tiny")
    save_model(model, root / "model")
    # obstacle in the base frame: a box beside the predicted geometry; world = base + (1, 2, 3)
    box = trimesh.creation.box(extents=[0.04, 0.2, 0.2])
    box.apply_translation(np.array([0.06, 0.0, 0.1]) + [1.0, 2.0, 3.0])
    box.export(root / "box.stl")
    opened = trimesh.Trimesh(box.vertices, box.faces[:-1], process=False)
    opened.export(root / "open.stl")
    return root


def _run(args):
    return runner.invoke(app, ["plan", "chest", *args])


def test_plan_chest_tiny(tiny, tmp_path):
    out = tmp_path / "out"
    args = [
        "--model",
        str(tiny / "model"),
        "--env",
        str(tiny / "box.stl"),
        "--base-pose",
        "1,2,3,1,0,0,0",
        "--goal",
        "0.03,0.03",
        "--milestones",
        "20",
        "--iterations",
        "3",
        "--candidates",
        "32",
        "--least-risk",
        "--executions",
        "0",
        "--out",
        str(out),
    ]
    res = _run(args)
    assert res.exit_code == 0, res.output
    for f in (
        "nominal.json",
        "nominal.csv",
        "optimised.json",
        "optimised.csv",
        "trace.json",
        "trace.png",
        "chest.html",
        "plan.json",
        "nominal_plan.csv",
        "nominal_plan.json",
        "optimised_plan.joint_trajectory.yaml",
    ):
        assert (out / f).stat().st_size > 0, f
    plan = json.loads((out / "plan.json").read_text())
    nominal = json.loads((out / "nominal.json").read_text())
    opt = json.loads((out / "optimised.json").read_text())
    trace = json.loads((out / "trace.json").read_text())["trace"]
    assert (
        len(trace) == 4
        and trace[0] == pytest.approx(nominal["bound_eq10"])
        and trace[-1] == pytest.approx(opt["bound_eq10"])
    )
    assert opt["bound_eq10"] <= nominal["bound_eq10"]
    assert (
        plan["paths"]["least_risk"]["bound_eq10"]
        <= plan["paths"]["shortest"]["bound_eq10"] + TOL["float64_abs"]["atol"]
    )
    assert nominal["configurations"][0] == [0.0, 0.0] and nominal["configurations"][-1] == [
        0.03,
        0.03,
    ]
    csv = (out / "optimised.csv").read_text().splitlines()
    assert csv[1].startswith("index,d1_m,d2_m,bound_eq9") and len(csv) == 2 + len(
        opt["configurations"]
    )
    # the controller's files carry the same trajectory (a model without a robot: no tensions)
    from riskplan.planning.export import read_tendon_plan

    exported = read_tendon_plan(out / "optimised_plan.json")
    assert exported.displacements.tolist() == opt["configurations"]
    assert exported.risk.tolist() == opt["bounds_eq9"] and exported.tensions is None
    # --resume after completion returns the same optimised trajectory
    res2 = _run(args + ["--resume"])
    assert res2.exit_code == 0, res2.output
    assert json.loads((out / "optimised.json").read_text()) == opt


@pytest.mark.parametrize(
    "extra, error, match",
    [
        (["--goal", "0.05,0.0"], InvalidInputError, "outside the displacement limits"),
        (["--goal", "0.01"], InvalidInputError, "expected 2 comma-separated numbers"),
        (["--radius", "nan"], InvalidInputError, "--radius"),
        (["--robot", "paper"], DataFormatError, "tendons"),
        (["--goal-tip", "0,0,0.9"], PlanningError, "unreachable"),
        (["--risk", "eq11"], InvalidInputError, "risk"),
    ],
)
def test_plan_chest_errors(tiny, tmp_path, extra, error, match):
    out = tmp_path / "out"
    args = [
        "--model",
        str(tiny / "model"),
        "--env",
        str(tiny / "box.stl"),
        "--base-pose",
        "1,2,3,1,0,0,0",
        "--milestones",
        "10",
        "--iterations",
        "1",
        "--executions",
        "0",
        "--out",
        str(out),
        *extra,
    ]
    res = _run(args)
    assert isinstance(res.exception, error), res.output
    assert match in str(res.exception)
    assert not out.exists() or not any(out.iterdir())  # nothing half-written


def test_plan_chest_mesh_and_frame_errors(tiny, tmp_path):
    base = ["--model", str(tiny / "model"), "--out", str(tmp_path / "o")]
    res = _run(base + ["--env", str(tiny / "box.stl")])
    assert isinstance(res.exception, InvalidInputError) and "--base-pose" in str(res.exception)
    res = _run(base + ["--env", str(tiny / "open.stl"), "--base-pose", "1,2,3,1,0,0,0"])
    assert isinstance(res.exception, InvalidInputError) and "closed" in str(res.exception)


def test_plan_chest_reads_the_mesh_sidecar(tiny, tmp_path):
    """A mesh with the sidecar that `riskplan env chest` writes needs no --base-pose, and gives the
    same plan as the same mesh with the pose given explicitly (one frame convention everywhere)."""
    import shutil

    from riskplan.collision.mesh_files import BasePose, sidecar_path

    mesh = tmp_path / "box.stl"
    shutil.copy(tiny / "box.stl", mesh)
    pose = BasePose.from_quaternion([1.0, 2.0, 3.0], [1.0, 0.0, 0.0, 0.0])
    sidecar_path(mesh).write_text(json.dumps({"frame": "world", **pose.to_json()}))
    common = [
        "--model",
        str(tiny / "model"),
        "--goal",
        "0.03,0.03",
        "--milestones",
        "20",
        "--iterations",
        "1",
        "--candidates",
        "16",
        "--executions",
        "0",
    ]
    a = _run(common + ["--env", str(mesh), "--out", str(tmp_path / "a")])
    b = _run(
        common
        + [
            "--env",
            str(tiny / "box.stl"),
            "--base-pose",
            "1,2,3,1,0,0,0",
            "--out",
            str(tmp_path / "b"),
        ]
    )
    assert a.exit_code == 0 and b.exit_code == 0, a.output + b.output
    na = json.loads((tmp_path / "a" / "nominal.json").read_text())
    nb = json.loads((tmp_path / "b" / "nominal.json").read_text())
    assert na["configurations"] == nb["configurations"]
    assert na["bound_eq10"] == pytest.approx(nb["bound_eq10"], **approx_tol("float64_exact_rel"))


def test_plan_chest_with_the_cloud_risk(tiny, tmp_path):
    """``--risk cloud`` optimises the body-contact risk; the plan records which risk it used."""
    out = tmp_path / "out"
    args = ["--model", str(tiny / "model"), "--env", str(tiny / "box.stl"), "--base-pose"]
    args += ["1,2,3,1,0,0,0", "--goal", "0.03,0.03", "--milestones", "20", "--iterations", "2"]
    args += ["--candidates", "16", "--executions", "0", "--risk", "cloud", "--out", str(out)]
    res = _run(args)
    assert res.exit_code == 0, res.output
    assert "cloud risk" in res.output
    plan = json.loads((out / "plan.json").read_text())
    assert plan["settings"]["risk"] == "cloud"
    nominal = json.loads((out / "nominal.json").read_text())
    assert all(0.0 <= p <= 1.0 for p in nominal["bounds_eq9"])


def test_plan_chest_env_in_millimetres_is_refused(tmp_path):
    """The --env mesh's units are judged against the model's robot before anything is written:
    a mesh in millimetres is refused with the option, the ratio and the units named."""
    import trimesh

    from riskplan.kinematics import MDN, MDNModel, Normalisation, save_model
    from riskplan.robots import load_robot

    rob = load_robot("paper")
    m = rob.n_tendons
    torch.manual_seed(0)
    net = MDN(m, 2, hidden=(8,), head_hidden=()).double()
    norm = Normalisation(
        np.full(m, 0.015), np.full(m, 0.015), np.array([0.0, 0.0, 0.1]), np.full(3, 0.02)
    )
    lim = np.tile([-0.01, 0.04], (m, 1))
    save_model(
        MDNModel(net, norm, lim, robot_name=rob.name, robot_toml=rob.toml_text()),
        tmp_path / "model",
    )
    box = trimesh.creation.box(extents=[0.04, 0.2, 0.2])
    box.apply_translation([0.06, 0.0, 0.1])
    box.apply_scale(1000.0)
    box.export(tmp_path / "mm.stl")
    out = tmp_path / "out"
    res = _run(
        ["--model", str(tmp_path / "model"), "--env", str(tmp_path / "mm.stl")]
        + ["--base-pose", "0,0,0,1,0,0,0", "--milestones", "10", "--executions", "0"]
        + ["--out", str(out)]
    )
    assert isinstance(res.exception, InvalidInputError), res.output
    msg = str(res.exception)
    assert "--env" in msg and "times the robot's length" in msg and "millimetres" in msg
    assert not out.exists() or not any(out.iterdir())
