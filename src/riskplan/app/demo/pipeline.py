"""``riskplan demo``: run every stage on embedded defaults and write one HTML report.

Stages run in pipeline order and share a context dict (e.g. the robot stage puts
the data-set paths there, the kinematics stage the trained model). Each stage is a
module ``riskplan.app.demo.<area>`` with

    def run(report: Report, ctx: dict, *, seed: int, workers: int | None) -> None
"""

from __future__ import annotations

import importlib
import logging
import time
from pathlib import Path

from riskplan.app.report import Report

log = logging.getLogger(__name__)

STAGES = ("robot", "kinematics", "collision", "tissue", "planning", "planning_tissue")


def run_demo(
    out, *, seed: int = 0, workers: int | None = None, stages=STAGES, progress=None
) -> Path:
    """Run ``stages`` in order into ``out`` and write ``out/report.html``; returns its path.

    ``progress(done, total, stage, seconds)`` is called before each stage (``seconds=None``) and
    after it (with its run time), whatever the stages are.
    """
    from riskplan._validation import check_count, check_workers
    from riskplan.io import check_output_folder

    out = check_output_folder(out, "out")
    check_count(seed, "seed", 0)
    check_workers(workers)
    stages = tuple(stages)
    report = Report(out, title="riskplan demo")
    ctx: dict = {"out": out}
    timings = []
    for k, name in enumerate(stages):
        mod = importlib.import_module(f"riskplan.app.demo.{name}")
        if progress is not None:
            progress(k, len(stages), name, None)
        t0 = time.perf_counter()
        log.info("demo stage %s", name)
        mod.run(report, ctx, seed=seed, workers=workers)
        timings.append([name, time.perf_counter() - t0])
        if progress is not None:
            progress(k + 1, len(stages), name, timings[-1][1])
    sec = report.section("Run time")
    Report.table(sec, ["stage", "seconds"], timings)
    return report.write()
