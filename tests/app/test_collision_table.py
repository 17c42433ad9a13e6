"""Bound-vs-Monte-Carlo table and the collision demo stage, at small scale."""

from __future__ import annotations

import numpy as np

from riskplan.app.outputs.collision_table import collision_table, to_markdown
from tests.conftest import TOL


def test_table_bound_covers_monte_carlo():
    rows, meta = collision_table(seed=0, n_samples=3000, use_robot=False, trajectory_steps=5)
    assert meta["triangles"] > 3000 and len(rows) == meta["configurations"] + 1
    eps = TOL["float64_abs"]["atol"]
    for r in rows:
        assert 0 <= r["bound"] <= 1 and r["mc_low"] <= r["mc"] <= r["mc_high"]
        assert r["bound"] >= r["mc_low"] - eps, r
        if not np.isnan(r["union"]):
            assert r["union"] >= r["mc_union_low"] - eps, r
            assert r["union"] >= r["bound"] - eps
    assert rows[0]["bound"] < 0.05  # home is nearly free
    assert max(r["bound"] for r in rows) > 0.2  # bent shapes touch organs
    text = to_markdown(rows, meta)
    assert (
        text.count("\n|") == len(rows) + 2
    )  # header separator + rows (the header starts after a blank line)


def test_demo_stage(tmp_path):
    from riskplan.app.demo import collision as demo_collision
    from riskplan.app.report import Report

    report = Report(tmp_path)
    ctx = {"out": tmp_path}
    demo_collision.run(report, ctx, seed=0, workers=1)
    report.write()
    assert (tmp_path / "collision_chest.png").exists() and (
        tmp_path / "collision_sweep.png"
    ).exists()
    assert ctx["environment"].n_faces == ctx["chest"].n_triangles


def test_table_with_robot_configurations():
    from tests.collision.test_robot_geometry import _ArcRobot

    rows, meta = collision_table(seed=0, n_samples=1000, robot=_ArcRobot(), trajectory_steps=3)
    assert meta["geometry"] == "robot backbone"
    assert rows[0]["label"].startswith("home") and len(rows) == 4 * 2 + 2 + 1
    assert all(r["bound"] >= r["mc_low"] - TOL["float64_abs"]["atol"] for r in rows)
