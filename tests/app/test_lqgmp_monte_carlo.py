"""The LQG-MP calibration check runs at small scale and reports rates inside their intervals."""

from __future__ import annotations

from riskplan.app.reproduce.lqgmp_monte_carlo import needle_rows


def test_nominal_row():
    (row,) = needle_rows(cases=("nominal",), n=20, seed=0)
    assert row["steps"] > 5 and row["plan"] == "margin"
    for name in ("closed", "closed_identity", "open"):
        p, lo, hi = row[name]
        assert lo <= p <= hi
    # without parameter uncertainty the plan (which reaches the goal) succeeds: sensing noise only
    assert row["lqgmp_sigma"] > 0.9 and row["closed"][0] == 1.0
    assert row["lqgmp_sampling"] >= row["lqgmp_sigma"] - 0.05  # sigma is the conservative one


def test_unknown_plan():
    import pytest

    from riskplan.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="plan"):
        needle_rows(cases=("nominal",), n=1, plan="fast")
