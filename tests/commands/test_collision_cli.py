"""CLI smoke tests for `riskplan env chest`, `riskplan collision`, `riskplan collision-table`."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.collision import Environment

runner = CliRunner()


def test_env_chest(tmp_path):
    out = tmp_path / "chest.stl"
    res = runner.invoke(app, ["env", "chest", "--out", str(out), "--subdivisions", "2", "--view", str(tmp_path / "c.png")])
    assert res.exit_code == 0, res.output
    env = Environment.load(out)
    meta = json.loads((tmp_path / "chest.stl.json").read_text())
    assert env.n_faces == meta["triangles"]
    assert (tmp_path / "c.png").stat().st_size > 1000


def test_collision_arc_json():
    res = runner.invoke(app, ["collision", "--arc", "8,0", "--samples", "2000", "--json"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)
    assert rows[0]["probability"] >= rows[0]["mc_low"]


def test_collision_requires_configuration():
    res = runner.invoke(app, ["collision"])
    assert res.exit_code != 0


def test_collision_robot_configurations():
    res = runner.invoke(app, ["collision", "-d", "0,0,0,0;0.02,0,0,0", "--samples", "2000", "--json"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)
    assert len(rows) == 2 and rows[1]["probability"] > rows[0]["probability"]
    assert all(r["probability"] >= r["mc_low"] for r in rows)
