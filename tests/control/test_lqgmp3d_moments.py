"""LQG-MP in 3-D on the second-order model: the truncation by a half-space on a position
with its own residual against Monte Carlo, the linear model written as a second-order one
gives the linear results, and the model's final tip distribution against closed-loop
executions of the 3-D needle (Monte Carlo oracle, 95 %-style intervals at z = 4)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from riskplan.control import NominalPlan, linearize
from riskplan.control.lqg import execute, lqg_controller
from riskplan.control.lqgmp3d import _model, _truncate_step, lqgmp_3d
from riskplan.control.lqgmp3d_moments import (
    SecondOrderModel,
    second_order_model,
    structured_linearization,
)
from riskplan.errors import InvalidInputError
from riskplan.parallel import spawn_seeds
from riskplan.scenarios.registry import scenario_from_config

#: z-score of the Monte Carlo checks
Z = 4.0


def test_truncation_with_a_position_residual_matches_monte_carlo():
    """y = P ξ + ε with Cov(ξ, ε) ≠ 0, conditioned on cᵀ(y − ȳ) ≤ d: the truncated mean of
    ξ against the mean of the draws that satisfy it."""
    gen = np.random.default_rng(3)
    n2 = 6
    G = gen.standard_normal((n2 + 3, n2 + 3)) * 0.3
    C = G @ G.T + 0.05 * np.eye(n2 + 3)
    S, cross, R = C[:n2, :n2], C[:n2, n2:], C[n2:, n2:]
    mu = gen.standard_normal(n2) * 0.1
    P = gen.standard_normal((3, n2))
    Sp = P @ S @ P.T + R + P @ cross + cross.T @ P.T
    Lc = np.linalg.cholesky(Sp)
    nrm = np.array([0.6, 0.0, 0.8])
    d = 0.3
    m, _ = _truncate_step(mu, S, P, R, cross, Lc, [(nrm, d)])
    draws = np.concatenate([mu, np.zeros(3)]) + gen.standard_normal((400_000, n2 + 3)) @ (
        np.linalg.cholesky(C).T
    )
    y = draws[:, :n2] @ P.T + draws[:, n2:] - P @ mu
    keep = np.linalg.solve(Lc, y.T).T @ nrm <= d
    kept = draws[keep, :n2]
    se = kept.std(axis=0) / np.sqrt(keep.sum())
    assert np.all(np.abs(kept.mean(axis=0) - m) <= Z * se)
    assert np.any(np.abs(mu - m) > Z * se)  # the truncation did move the mean


@pytest.fixture(scope="module")
def needle():
    """A 14-step plan of the 3-D needle (case actuation), its LQG controller and 300
    closed-loop executions' final world tips."""
    sim = scenario_from_config("needle3d", None, "actuation")
    controls = np.tile([[0.35, -2.0]], (14, 1))  # clear of the obstacles
    controls[7:, 1] = 2.0
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), controls)
    ctrl = lqg_controller(linearize(sim, plan, n_samples=16, seed=0))
    tips = []
    for s in spawn_seeds(1, 300):
        gen = np.random.default_rng(s)
        ex = execute(sim, plan, ctrl, sim.sample_params(gen), seed=gen, keep_states=False)
        tips.append(ex.x[-1][:3])
    return sim, plan, ctrl, np.array(tips)


def test_second_order_model_predicts_the_executions_final_tip(needle):
    """The model's final world tip (x*_T + offset + P mean_T, P cov_T Pᵀ + R) against 300
    closed-loop executions: mean and standard deviations inside the Monte Carlo intervals."""
    sim, plan, ctrl, tips = needle
    mo = second_order_model(sim, plan, ctrl, np.array(sim.distribution.cov))
    res = lqgmp_3d(sim, plan, ctrl, method="per-step", moments=mo)
    T = plan.n_steps
    P, R = mo.P[-1], mo.resid[-1]
    mean = plan.reduced[T][:3] + mo.offset[-1] + P @ res.mean[T]
    sd = np.sqrt(np.diag(P @ res.cov[T] @ P.T + R))
    n = tips.shape[0]
    mc_sd = tips.std(axis=0, ddof=1)
    assert np.all(np.abs(tips.mean(axis=0) - mean) <= Z * mc_sd / np.sqrt(n))
    assert np.all(np.abs(sd - mc_sd) <= Z * mc_sd / np.sqrt(2 * n))


def test_linear_model_as_moments_gives_the_linear_results(needle, tol):
    """The linear model's recursion handed over as ``moments`` reproduces every method."""
    sim, plan, ctrl, _ = needle
    lin = _model(sim, plan, ctrl, np.arange(3), False, False, None)
    mo = SecondOrderModel(**{k: np.array(v) for k, v in lin.__dict__.items()})
    for method in ("truncation", "per-step", "sigma", "sampling"):
        a = lqgmp_3d(sim, plan, ctrl, method=method, seed=4, n_goal_samples=500)
        b = lqgmp_3d(sim, plan, ctrl, method=method, seed=4, n_goal_samples=500, moments=mo)
        np.testing.assert_allclose(a.p_success, b.p_success, **tol["float64_exact"])
        np.testing.assert_allclose(a.cov, b.cov, **tol["float64_exact"])


def test_bad_input(needle):
    sim, plan, ctrl, _ = needle
    W = np.array(sim.distribution.cov)
    with pytest.raises(InvalidInputError, match="actuation_cov"):
        second_order_model(sim, plan, ctrl, -W)
    with pytest.raises(InvalidInputError, match="has no"):
        second_order_model(object(), plan, ctrl, W)
    with pytest.raises(InvalidInputError, match="controller"):
        second_order_model(sim, plan, dataclasses.replace(ctrl, disturbance=True), W)
    short = NominalPlan.from_rollout(sim, sim.initial_state(), plan.controls[:3])
    with pytest.raises(InvalidInputError, match="controller"):
        second_order_model(sim, short, ctrl, W)
    mo = second_order_model(sim, plan, ctrl, W)
    with pytest.raises(InvalidInputError, match="moments"):
        lqgmp_3d(sim, plan, ctrl, moments="second-order")
    assert mo.n_steps == plan.n_steps


def test_structured_linearization_is_the_fitted_one_where_the_fit_is_exact(needle, tol):
    """The structured model's ``B`` against the fitted linearisation's forward differences
    (``ε = 10⁻³`` of the control range: first-order error), its scales as linearize sets
    them; a simulator without ``linear_model`` is rejected."""
    sim, plan, ctrl, _ = needle
    lin = structured_linearization(sim, plan, np.array(sim.distribution.cov))
    np.testing.assert_allclose(lin.B, ctrl.lin.B, **tol["fd_forward_force"])
    np.testing.assert_allclose(lin.state_scale, ctrl.lin.state_scale, **tol["float64_exact"])
    np.testing.assert_allclose(lin.control_scale, ctrl.lin.control_scale, **tol["float64_exact"])
    assert np.all(lin.rank == 12)
    with pytest.raises(InvalidInputError, match="linear_model"):
        structured_linearization(object(), plan, np.eye(2))
