"""LQG-MP plan selection: ranking, chosen plan and gains, backend independence, failed
candidates, and the check against closed-loop Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest

import riskplan.control
from riskplan.control.lqgmp import lqgmp
from riskplan.errors import InvalidInputError, SimulationError
from riskplan.scenarios.uncertainty import get_case
from riskplan.tissue_planning.calibration import calibration_check
from riskplan.tissue_planning.select import common_draws, evaluate_plan, select_plan
from tests.conftest import approx_tol
from tests.planning.conftest import SMALL_MESH

CASE = get_case("actuation", SMALL_MESH)


@pytest.fixture(scope="module")
def selection(near_needle, needle_result):
    plans, _ = needle_result
    return select_plan(
        near_needle, plans, CASE, n_samples=4, n_goal_samples=500, seed=5, backend="serial"
    )


def test_ranking_and_chosen_plan(near_needle, needle_result, selection):
    plans, _ = needle_result
    ps = [s.p_success for s in selection.ranking]
    assert ps == sorted(ps, reverse=True)
    assert sorted(s.index for s in selection.ranking) == list(range(len(plans)))
    assert selection.best == selection.ranking[0].index and selection.plan is plans[selection.best]
    for s in selection.ranking:
        assert 0.0 <= s.p_success <= 1.0 and s.error is None
        assert s.p_success == pytest.approx(
            s.p_collision_free * s.p_goal, **approx_tol("float64_exact_small")
        )
    # the chosen plan's gains fit its dimensions
    T, q, p = selection.plan.n_steps, near_needle.control_dim, near_needle.state_dim
    assert selection.controller.L.shape == (T, q, p)
    assert selection.controller.K.shape == (T, p, near_needle.obs_dim)
    # the stored result is LQG-MP of that plan and controller (P(no collision) does not
    # depend on the goal samples' seed)
    again = lqgmp(near_needle, selection.plan, selection.controller, n_goal_samples=500, seed=0)
    assert again.p_collision_free == pytest.approx(
        selection.result.p_collision_free, **approx_tol("float64_exact_small")
    )


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_evaluate_plan_matches_selection(near_needle, needle_result, selection):
    from riskplan.parallel import spawn_seeds

    plans, _ = needle_result
    i = selection.ranking[-1].index
    draws = common_draws(near_needle, CASE, 4, 5)
    assert len(draws) == 4 and draws == common_draws(near_needle, CASE, 4, 5)
    ctrl, res = evaluate_plan(
        near_needle, plans[i], draws, n_goal_samples=500, seed=spawn_seeds(5, len(plans))[i]
    )
    assert res.p_success == selection.score(i).p_success
    assert np.array_equal(ctrl.L, selection.controllers[i].L)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_n_a_runs_reaches_the_linearisation(near_needle, needle_result):
    # the paper's K = 2p instead of the default 2q: select_plan passes it to linearize
    from riskplan.parallel import spawn_seeds

    plans, _ = needle_result
    K = 2 * near_needle.state_dim
    sel = select_plan(
        near_needle,
        plans[:1],
        CASE,
        n_samples=2,
        n_goal_samples=200,
        n_a_runs=K,
        seed=3,
        backend="serial",
    )
    draws = common_draws(near_needle, CASE, 2, 3)
    seed = spawn_seeds(3, 1)[0]
    paper, _ = evaluate_plan(
        near_needle, plans[0], draws, n_goal_samples=200, n_a_runs=K, seed=seed
    )
    default, _ = evaluate_plan(near_needle, plans[0], draws, n_goal_samples=200, seed=seed)
    assert np.array_equal(sel.controllers[0].lin.A, paper.lin.A)
    assert not np.array_equal(paper.lin.A, default.lin.A)


def test_failed_candidate_scores_zero(near_needle, needle_result, monkeypatch):
    plans, _ = needle_result
    real = riskplan.control.linearize

    def flaky(sim, plan, *args, **kwargs):
        if plan is plans[0]:
            raise SimulationError("linearize: non-finite reduced state at step 3 (test)")
        return real(sim, plan, *args, **kwargs)

    monkeypatch.setattr(riskplan.control, "linearize", flaky)
    sel = select_plan(
        near_needle, plans[:2], CASE, n_samples=2, n_goal_samples=200, seed=1, backend="serial"
    )
    bad = sel.score(0)
    assert bad.p_success == 0.0 and "step 3" in bad.error
    assert sel.best == 1 and sel.controllers[0] is None


def test_calibration_check_rows(near_needle, needle_result, selection):
    plans, _ = needle_result
    rows = calibration_check(
        near_needle, plans, selection, CASE, others=1, n=60, seed=0, backend="serial"
    )
    assert [r.rank for r in rows] == [1, len(plans)]  # 1-based: 1 is the selected plan
    assert rows[0].index == selection.best
    for r in rows:
        assert r.n == 60 and 0.0 <= r.low <= r.p_mc <= r.high <= 1.0
        assert r.p_lqgmp == selection.score(r.index).p_success
    with pytest.raises(InvalidInputError, match="n:"):
        calibration_check(near_needle, plans, selection, CASE, n=0)


def test_empty_candidate_list_is_named(near_needle):
    with pytest.raises(InvalidInputError, match="plans"):
        select_plan(near_needle, [], CASE)
