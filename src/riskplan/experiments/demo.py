"""``riskplan demo``: run every stage on embedded defaults and write one HTML report.

Stages run in pipeline order and share a context dict (e.g. the robot stage puts
the data-set paths there, the kinematics stage the trained model). Each stage is a
module ``riskplan.experiments.demo_<area>`` with

    def run(report: Report, ctx: dict, *, seed: int, workers: int | None) -> None
"""

from __future__ import annotations

import importlib
import logging
import time
from pathlib import Path

from riskplan.experiments.report import Report

log = logging.getLogger(__name__)

STAGES = ("robot", "kinematics", "collision", "tissue", "planning_tissue")


def run_demo(out, *, seed: int = 0, workers: int | None = None, stages=STAGES) -> Path:
    out = Path(out)
    report = Report(out, title="riskplan demo")
    ctx: dict = {"out": out}
    timings = []
    for name in stages:
        mod = importlib.import_module(f"riskplan.experiments.demo_{name}")
        t0 = time.perf_counter()
        log.info("demo stage %s", name)
        mod.run(report, ctx, seed=seed, workers=workers)
        timings.append([name, time.perf_counter() - t0])
    sec = report.section("Run time")
    Report.table(sec, ["stage", "seconds"], timings)
    return report.write()
