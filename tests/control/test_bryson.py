"""Bryson's-rule default weights of lqg_controller, and what they buy: less final spread than
open loop on the linear toy and on the needle (Monte Carlo, standard errors)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from riskplan.control import (
    Linearization,
    bryson_weights,
    execute,
    linearize,
    lqg_controller,
    lqr_gains,
)
from riskplan.control.linearize import RankDeficiencyWarning
from riskplan.errors import InvalidInputError
from riskplan.scenarios.uncertainty import ActuationNoise

from .toy import LinearToy, square, toy_system


def test_bryson_weights_closed_form(tol):
    Q, R = bryson_weights([0.1, 2.0], [0.5])
    np.testing.assert_allclose(Q, np.diag([100.0, 0.25]), **tol["float64_exact"])
    np.testing.assert_allclose(R, [[4.0]], **tol["float64_exact"])
    with pytest.raises(InvalidInputError, match="state_scale"):
        bryson_weights([0.1, 0.0], [1.0])
    with pytest.raises(InvalidInputError, match="control_scale"):
        bryson_weights([0.1], [-1.0])


def _lin(rng, T=5, state_scale=None, control_scale=None):
    A, B, _ = toy_system(rng)
    p = B.shape[0]
    return Linearization(
        A=np.tile(A, (T, 1, 1)),
        B=np.tile(B, (T, 1, 1)),
        M=np.tile(0.01 * np.eye(p), (T, 1, 1)),
        H=np.tile(np.eye(p)[:2], (T, 1, 1)),
        N=np.tile(1e-4 * np.eye(2), (T, 1, 1)),
        rank=np.full(T, p),
        state_scale=state_scale,
        control_scale=control_scale,
    )


def test_default_weights_follow_declared_scales(rng, tol):
    xs, us = np.array([0.1, 0.2, 0.5]), np.array([1.0, 2.0, 4.0])
    lin = _lin(rng, state_scale=xs, control_scale=us)
    Q, R = bryson_weights(xs, us)
    np.testing.assert_allclose(
        lqg_controller(lin).L, lqr_gains(lin.A, lin.B, Q, R, Q), **tol["float64_exact"]
    )
    # explicit weights still override, and without declared scales the default is the identity
    identity = lqr_gains(lin.A, lin.B, np.eye(3), np.eye(3), np.eye(3))
    np.testing.assert_allclose(
        lqg_controller(lin, Q=np.eye(3), R=np.eye(3)).L,
        identity,
        **tol["float64_exact"],
    )
    bare = Linearization(A=lin.A, B=lin.B, M=lin.M, H=lin.H, N=lin.N, rank=lin.rank)
    np.testing.assert_allclose(lqg_controller(bare).L, identity, **tol["float64_exact"])
    with pytest.raises(InvalidInputError, match="state_scale"):
        _lin(rng, state_scale=[0.1, -1.0, 1.0])


def test_linearize_records_the_simulators_scales(rng):
    A, B, _ = toy_system(rng, scale=0.1)
    sim = LinearToy(A, B, u_max=2.0)
    plan_u = rng.uniform(-0.5, 0.5, (3, 3))
    from riskplan.control import NominalPlan

    plan = NominalPlan.from_rollout(sim, sim.initial_state(), plan_u)
    lin = linearize(sim, plan, seed=0)
    assert lin.state_scale is None
    np.testing.assert_array_equal(lin.control_scale, [2.0, 2.0, 2.0])
    sim.state_scale = np.array([0.05, 0.05, 0.3])
    np.testing.assert_array_equal(linearize(sim, plan, seed=0).state_scale, sim.state_scale)


def _final_sq(sim, plan, ctrl, n, dims=slice(0, 2)):
    """Squared final position deviations of n executions (common random numbers per run)."""
    out = np.empty(n)
    for k in range(n):
        gen = np.random.default_rng(1000 + k)
        params = sim.distribution.sample(gen)
        ex = execute(sim, plan, ctrl, params, seed=np.random.default_rng(k), keep_states=False)
        out[k] = np.sum((ex.x[-1] - plan.reduced[-1])[dims] ** 2)
    return out


def _less(a, b, z=3.0):
    """mean(a) < mean(b) by more than z standard errors of the paired difference."""
    d = b - a
    return d.mean() > z * d.std(ddof=1) / np.sqrt(len(d))


def test_bryson_feedback_shrinks_toy_spread(rng):
    from riskplan.control import NominalPlan

    A, B, _ = toy_system(rng, scale=0.1)
    sim = LinearToy(
        A,
        B,
        u_max=2.0,
        distribution=ActuationNoise(cov=tuple(map(tuple, 0.01 * np.eye(3)))),
    )
    sim.state_scale = np.full(3, 0.05)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), rng.uniform(-0.5, 0.5, (10, 3)))
    sim._goal = square(*plan.reduced[-1, :2], 0.1)
    lin = linearize(sim, plan, sim.distribution, n_samples=32, seed=1)
    open_ = _final_sq(sim, plan, None, 80)
    bryson = _final_sq(sim, plan, lqg_controller(lin), 80)
    identity = _final_sq(sim, plan, lqg_controller(lin, Q=np.eye(3), R=np.eye(3)), 80)
    assert _less(bryson, open_) and _less(bryson, identity)


def test_bryson_feedback_shrinks_needle_spread():
    from riskplan.control import NominalPlan
    from riskplan.scenarios.registry import make_scenario

    sim = make_scenario("needle", "actuation")
    # a plan below v_max (speed margin) so feedback has room in both directions
    u = np.tile([0.8 * sim.config.v_max, 0.15], (8, 1))
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RankDeficiencyWarning)
        lin = linearize(sim, plan, sim.distribution, n_samples=16, seed=0)
    np.testing.assert_array_equal(lin.state_scale, sim.state_scale)
    open_ = _final_sq(sim, plan, None, 80)
    bryson = _final_sq(sim, plan, lqg_controller(lin), 80)
    identity = _final_sq(sim, plan, lqg_controller(lin, Q=np.eye(3), R=np.eye(2)), 80)
    assert _less(bryson, open_) and _less(bryson, identity)


def test_scenarios_declare_state_scales(tol):
    from riskplan.scenarios.manipulation import ManipulationScenario
    from riskplan.scenarios.needle import NeedleScenario

    needle = NeedleScenario()
    r = needle.config.goal_radius
    np.testing.assert_allclose(
        needle.state_scale, [r, r, r / needle.config.r_min], **tol["float64_exact"]
    )
    manip = ManipulationScenario()
    assert manip.state_scale.shape == (manip.state_dim,)
    n = 2 + 2 * manip.config.n_boundary
    assert manip.state_scale[0] == manip.config.goal_radius and np.all(
        manip.state_scale[2:n] == 4 * manip.config.goal_radius
    )
    assert np.all(manip.state_scale[n:] == manip.config.f_max)  # the applied forces
