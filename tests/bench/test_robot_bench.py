"""The robot benchmark reports exactly the issue's keys (no timing assertions)."""

from __future__ import annotations

import numpy as np

from riskplan.bench import robot


def test_bench_keys():
    figures = robot.run(quick=True, include_dataset=False)
    assert set(figures) == {"tension_single_ms", "tension_batched_us_per_config", "displacement_single_ms", "dataset_small_s"}
    assert all(np.isfinite(figures[k]) and figures[k] > 0 for k in figures if k != "dataset_small_s")
