"""Demo stage "robot": data sets for the later stages and the report section."""

from __future__ import annotations

import numpy as np

from riskplan.app.demo import robot as demo_robot
from riskplan.app.report import Report
from riskplan.datasets import PRESETS, load_dataset


def test_demo_robot_stage(tmp_path):
    report = Report(tmp_path, title="t")
    ctx = {"out": tmp_path}
    demo_robot.run(report, ctx, seed=0, workers=1)
    assert ctx["robot"].name == "paper"
    tr, te = load_dataset(ctx["train_path"]), load_dataset(ctx["test_path"])
    p = PRESETS["small"]
    assert tr.complete and te.complete
    assert tr.points.shape == (p.n_train, p.n_starts, p.n_points, 3)
    assert te.points.shape == (p.n_test, p.n_starts, p.n_points, 3)
    assert np.all(tr.tip_spread() >= 0) and tr.tip_spread().max() > 0
    for name in ("robot_shapes", "robot_clouds", "robot_cameras"):
        assert (tmp_path / f"{name}.png").stat().st_size > 1000
    html = report.write().read_text()
    assert "tip spread" in html
    # a second run reuses the finished files
    before = ctx["train_path"].stat().st_mtime_ns
    demo_robot.run(Report(tmp_path / "again"), {"out": tmp_path}, seed=0, workers=1)
    assert ctx["train_path"].stat().st_mtime_ns == before
