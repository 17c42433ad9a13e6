"""CLI: the lab's files through --robot, base rotation/retraction, the robot template, a
3-tendon robot's data set, start/goal in tensions."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.robots import load_robot
from tests.conftest import TOL

runner = CliRunner()
TASK = Path(__file__).resolve().parents[1] / "data" / "kuntz-lab" / "task-0001.toml"


def test_robot_info_and_shape_on_the_labs_task_file():
    res = runner.invoke(app, ["robot", "info", "--robot", str(TASK), "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert info["base_rotation"] and info["base_retraction"] and len(info["tendons"]) == 3
    # riskplan's angle: pi/2 - C of the lab's C = [1.571, 50]
    np.testing.assert_allclose(
        info["tendons"][1]["theta"], [np.pi / 2 - 1.571, -50.0], **TOL["float64_abs"]
    )
    res = runner.invoke(
        app,
        ["robot", "shape", "--robot", str(TASK), "--tensions", "3,1,0"]
        + ["--rotation", "-1.5", "--retraction", "0.07", "--json"],
    )
    assert res.exit_code == 0, res.output
    ref = load_robot(TASK).solve_tensions([3, 1, 0], rotation=-1.5, retraction=0.07)
    np.testing.assert_allclose(json.loads(res.output)["tip"], ref.tip, **TOL["float64_exact"])


def test_unknown_key_is_named_with_the_closest(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(TASK.read_text().replace("enable_rotation", "enable_rotaton"))
    res = runner.invoke(app, ["robot", "info", "--robot", str(bad)])
    assert res.exit_code != 0
    msg = str(res.exception)
    assert "tendon_robot.enable_rotaton" in msg and "did you mean 'enable_rotation'" in msg


def test_template_parses_and_is_refused_over_an_existing_file(tmp_path):
    out = tmp_path / "mine.toml"
    res = runner.invoke(app, ["robot", "template", "--out", str(out)])
    assert res.exit_code == 0, res.output
    robot = load_robot(out)
    assert robot.n_tendons == 3 and robot.name == "my-robot"
    assert tomllib.loads(out.read_text())["backbone"]["length"] == 0.15
    assert out.read_text().count("#") > 30  # commented
    res = runner.invoke(app, ["robot", "template", "--out", str(out)])
    assert res.exit_code != 0 and "--overwrite" in str(res.exception)
    res = runner.invoke(app, ["robot", "template"])
    assert res.exit_code == 0 and res.output == out.read_text()


def test_dataset_generate_on_a_three_tendon_robot(tmp_path):
    """The issue's case: `--preset small` on a 3-tendon robot used to fail (75 > 27 grid points)."""
    out = tmp_path / "mine.toml"
    assert runner.invoke(app, ["robot", "template", "--out", str(out)]).exit_code == 0
    res = runner.invoke(
        app,
        ["dataset", "generate", "--robot", str(out), "--preset", "tiny"]
        + ["--out", str(tmp_path / "d.h5"), "--split", "test", "--workers", "1"],
    )
    assert res.exit_code == 0, res.output
    help_text = runner.invoke(app, ["dataset", "generate", "--help"]).output
    assert "grid_levels" in help_text and "n_train" in help_text


def test_plan_chest_takes_start_and_goal_in_tensions(tmp_path):
    """Tensions are converted through the robot; out-of-limit tensions fail before any output."""
    out = tmp_path / "plan"
    res = runner.invoke(
        app,
        ["plan", "chest", "--model", "paper", "--goal-tensions", "12,0,0,0", "--out", str(out)],
    )
    msg = str(res.exception)
    assert res.exit_code != 0 and "--goal-tensions" in msg and "max_tension" in msg
    assert not out.exists()
    res = runner.invoke(
        app,
        ["plan", "chest", "--model", "paper", "--goal", "0.01,0,0,0"]
        + ["--goal-tensions", "1,0,0,0", "--out", str(out)],
    )
    assert res.exit_code != 0 and "not both" in str(res.exception) and not out.exists()


def test_predict_and_collision_take_tensions():
    """--tensions gives the same result as --displacements converted through the robot."""
    robot = load_robot("paper")
    tau = np.array([[2.0, 0.0, 1.0, 0.5], [0.0, 3.0, 0.0, 0.0]])
    d = robot.displacements_for_tensions(tau)
    spec_t = ";".join(",".join(repr(float(v)) for v in row) for row in tau)
    spec_d = ";".join(",".join(repr(float(v)) for v in row) for row in d)
    a = runner.invoke(app, ["predict", "--model", "paper", "--tensions", spec_t, "--json"])
    b = runner.invoke(app, ["predict", "--model", "paper", "--displacements", spec_d, "--json"])
    assert a.exit_code == 0 and b.exit_code == 0, a.output + b.output
    np.testing.assert_allclose(
        json.loads(a.output)["means"], json.loads(b.output)["means"], **TOL["solver"]
    )
    a = runner.invoke(
        app, ["collision", "probability", "--tensions", spec_t, "--json", "--samples", "100"]
    )
    b = runner.invoke(
        app, ["collision", "probability", "--displacements", spec_d, "--json", "--samples", "100"]
    )
    assert a.exit_code == 0 and b.exit_code == 0, a.output + b.output
    pa = [r["probability"] for r in json.loads(a.output)]
    pb = [r["probability"] for r in json.loads(b.output)]
    np.testing.assert_allclose(pa, pb, **TOL["solver"])
    bad = runner.invoke(app, ["predict", "--model", "paper", "--tensions", "20,0,0,0"])
    assert bad.exit_code != 0 and "max_tension" in str(bad.exception)


def test_configuration_forms_convert_both_ways():
    lab = load_robot(TASK)
    q = np.array([[1.0, 0.5, 2.0, 0.3, 0.05], [0.0, 3.0, 0.2, -2.0, 0.11]])
    qd = lab.configuration_to_displacements(q)
    np.testing.assert_array_equal(qd[:, 3:], q[:, 3:])
    np.testing.assert_allclose(lab.configuration_to_tensions(qd), q, **TOL["tension_solve"])
