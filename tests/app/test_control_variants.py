"""The control-variants stage: common draws, paired counts that add up, Wilson intervals
around the rates, resumable from its store."""

from __future__ import annotations

import pytest

from riskplan.app.reproduce import control_variants as cv
from riskplan.app.store import ResultStore
from riskplan.errors import InvalidInputError


def test_stage_rows_and_resume(tmp_path, monkeypatch):
    store = ResultStore(tmp_path / "store", {"seed": 0})
    res = cv.run_control_variants(store, "smoke", seed=0, scenarios=("needle",))
    assert res["scale"]["name"] == "smoke" and set(res) == {"scale", "needle"}
    row = res["needle"]["material-high"]
    # the executed plan is the best candidate by LQG-MP
    assert row["p_success"][row["plan"]] == max(row["p_success"])
    lqg = row["lqg"]
    for k in cv.VARIANTS:
        v = row[k]
        assert v["n"] == row["n"] == cv.CONTROL_SCALES["smoke"].n_executions
        assert sum(v["outcomes"].values()) == v["n"]
        assert v["low"] <= v["rate"] <= v["high"]
        # paired counts against LQG on the same draws
        assert v["successes"] - lqg["successes"] == v["won"] - v["lost"]
        assert v["cpu_s_per_execution"] > 0 and v["setup_cpu_s"] > 0
    assert lqg["won"] == lqg["lost"] == 0
    assert row["ilqr_linearizations"] >= 1
    assert all(b < a for a, b in zip(row["ilqr_costs"], row["ilqr_costs"][1:]))

    # a second run reads every row from the store
    def boom(*a, **k):
        raise AssertionError("recomputed")

    monkeypatch.setattr(cv, "compare_on_plan", boom)
    again = cv.run_control_variants(store, "smoke", seed=0, scenarios=("needle",))
    assert again["needle"] == res["needle"]
    with pytest.raises(InvalidInputError, match="scale"):
        cv.run_control_variants(store, "huge")
