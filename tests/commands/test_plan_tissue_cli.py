"""``riskplan plan tissue`` end to end at the smallest size, and its input errors."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from riskplan.cli import app

runner = CliRunner()


def test_plan_tissue_manipulation_small(tmp_path):
    res = runner.invoke(
        app,
        [
            "plan",
            "tissue",
            "--scenario",
            "manipulation",
            "--plans",
            "2",
            "--case",
            "actuation",
            "--out",
            str(tmp_path),
            "--workers",
            "1",
            "--check-runs",
            "20",
            "--check-others",
            "1",
            "--no-gif",
        ],
    )
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / "selected.json").read_text())
    assert meta["n_candidates"] == 2 and 0.0 <= meta["p_success"] <= 1.0
    assert [r["n"] for r in meta["calibration_check"]] == [20, 20]
    assert (tmp_path / "candidates.png").stat().st_size > 0
    assert "LQG-MP P(success)" in res.output


def test_plan_tissue_bad_scenario(tmp_path):
    res = runner.invoke(app, ["plan", "tissue", "--scenario", "liver", "--out", str(tmp_path)])
    assert res.exit_code != 0
    assert "scenario" in str(res.exception) or "scenario" in res.output
