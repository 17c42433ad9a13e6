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


def test_needle3d_rows_grouped_by_mesh_equal_the_executions_in_seed_order():
    """The 3-D needle in the mesh case: the executions run grouped by grid, and the
    counts are those of the same executions one by one in seed order; iLQR's terms there
    include the 3-D barrier (its cost falls strictly)."""
    import warnings

    import numpy as np

    from riskplan.control import NominalPlan, execute
    from riskplan.control.ilqr import tracking_controller
    from riskplan.parallel import spawn_seeds
    from riskplan.scenarios.registry import make_scenario

    sim = make_scenario("needle3d", "mesh")
    u = np.tile([0.45, 0.0], (8, 1))
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    n = 6
    row = cv.compare_on_plan(sim, plan, n, seed=3, lin_samples=2)
    seeds = spawn_seeds(3, n)
    draws = [sim.distribution.sample(np.random.default_rng([s, 0])) for s in seeds]
    assert len({cv._mesh_group(sim, p) for p in draws}) > 1  # several meshes, reordered
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        pl, ctrl, _ = tracking_controller(sim, plan, sim.distribution, n_samples=2, seed=3)
    outcomes = [
        execute(sim, pl, ctrl, p, seed=np.random.default_rng([s, 1]), keep_states=False).outcome
        for s, p in zip(seeds, draws)
    ]
    assert row["lqg"]["outcomes"] == {x: outcomes.count(x) for x in sorted(set(outcomes))}
    assert (
        row["ukf"]["successes"] - row["lqg"]["successes"] == row["ukf"]["won"] - row["ukf"]["lost"]
    )
    assert all(b < a for a, b in zip(row["ilqr_costs"], row["ilqr_costs"][1:]))
    assert len(row["ilqr_costs"]) >= 2
