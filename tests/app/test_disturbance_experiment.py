"""The disturbance-state comparison runs at small scale and reports one row per case."""

from __future__ import annotations

import pytest

from riskplan.app.reproduce.disturbance import CONTROLLERS, disturbance_rows
from tests.conftest import approx_tol


def test_actuation_row_has_no_persistent_part():
    (row,) = disturbance_rows(
        "manipulation", cases=("actuation",), n=4, n_samples=4, backend="serial"
    )
    assert row["scenario"] == "manipulation" and row["steps"] >= 1
    # actuation noise is per-step: Σ_d = 0, the whole process noise stays in M^r and the
    # disturbance-state loop is the paper's (d̂ stays 0), run by run on the same draws
    assert row["trace_sigma_d"] == 0.0
    assert row["residual_share"] == pytest.approx(1.0, **approx_tol("float64_exact"))
    assert row["plain"] == row["disturbance"]
    for name in CONTROLLERS:
        k, n, lo, hi = row[name]
        assert n == 4 and lo <= k / n <= hi
