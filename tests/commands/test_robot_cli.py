"""CLI tests for `riskplan robot shape` / `riskplan robot info`."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.robots import load_robot
from tests.conftest import TOL

runner = CliRunner()


def test_shape_json_displacements():
    res = runner.invoke(app, ["robot", "shape", "--robot", "paper", "--displacements", "0.01,0,0,0", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert set(out) == {"tip", "backbone", "tensions"}
    ref = load_robot("paper").solve_displacements([0.01, 0, 0, 0])
    np.testing.assert_allclose(out["tip"], ref.tip, **TOL["float64_exact"])
    assert np.array(out["backbone"]).shape == (41, 3) and len(out["tensions"]) == 4


def test_shape_tensions_plot_and_file_robot(tmp_path):
    f = tmp_path / "r.toml"
    f.write_text(load_robot("paper").toml_text())
    png = tmp_path / "s.png"
    res = runner.invoke(app, ["robot", "shape", "--robot", str(f), "--tensions", "1,0,0,2", "--plot", str(png)])
    assert res.exit_code == 0, res.output
    assert "tip" in res.output and png.stat().st_size > 1000


def test_shape_bad_input_is_a_clean_error():
    res = runner.invoke(app, ["robot", "shape", "--displacements", "0.05,0,0,0"])
    assert res.exit_code != 0
    assert "0.04" in str(res.exception) or "0.04" in res.output
    res = runner.invoke(app, ["robot", "shape"])
    assert res.exit_code != 0


def test_info_json():
    res = runner.invoke(app, ["robot", "info", "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads(res.output)
    assert d["name"] == "paper" and len(d["tendons"]) == 4 and d["tendons"][3]["max_tension_n"] == 16.81
