"""The control benchmark runs and reports its keys (no timing assertions)."""

from __future__ import annotations

import numpy as np

from riskplan.bench import control


def test_bench_keys():
    figures = control.run(quick=True)
    assert {
        "needle_linearize_ms",
        "needle_lqgmp_sigma_ms",
        "needle_per_plan_ms",
        "needle_mc_50_s",
    } <= set(figures)
    assert figures["needle_plan_steps"] > 5
    assert all(np.isfinite(v) and v > 0 for v in figures.values())
