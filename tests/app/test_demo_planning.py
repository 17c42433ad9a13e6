"""The planning demo stage runs on a model in ctx (small settings) and skips without one."""

from __future__ import annotations

from riskplan.app.demo import planning as demo_planning
from riskplan.app.report import Report
from tests.planning.conftest import AnalyticModel


def test_stage_runs(tmp_path, monkeypatch):
    monkeypatch.setattr(demo_planning, "MILESTONES", 30)
    monkeypatch.setattr(demo_planning, "ITERATIONS", 2)
    monkeypatch.setattr(demo_planning, "CANDIDATES", 32)
    report = Report(tmp_path, title="t")
    # gain 1: the tip stays within 2.5 cm of the straight pose, free at zero displacement in the chest
    ctx = {"out": tmp_path, "model": AnalyticModel(gain=1.0)}
    demo_planning.run(report, ctx, seed=0, workers=1)
    plan = ctx["chest_plan"]
    assert plan["optimised_bound"] <= plan["nominal_bound"]
    assert (report.write()).stat().st_size > 0
    assert any(tmp_path.rglob("planning_fig7*"))


def test_stage_skips_without_model(tmp_path):
    report = Report(tmp_path, title="t")
    ctx = {"out": tmp_path}
    demo_planning.run(report, ctx, seed=0, workers=1)
    assert "chest_plan" not in ctx
