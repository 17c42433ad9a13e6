"""LQG-MP of the 3-D needle by Monte Carlo of the reduced closed loop: the batched material
step against the simulator's step, the particles with the step linearised against the
linear-Gaussian recursion they then are (moments in closed form), and with the exact step
against closed-loop executions of a plan that passes close to an obstacle — the success
rate and the final tip's skewness, which the Gaussian closure cannot have (Monte Carlo
oracles at z = 4)."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from riskplan.collision import binomial_interval
from riskplan.control import NominalPlan, linearize
from riskplan.control.lqg import execute, lqg_controller
from riskplan.control.lqgmp3d import binomial_se
from riskplan.control.lqgmp3d_moments import second_order_model
from riskplan.control.lqgmp3d_particles import _run, draw_until, lqgmp_particles
from riskplan.errors import InvalidInputError
from riskplan.parallel import spawn_seeds
from riskplan.scenarios.registry import scenario_from_config

#: z-score of the Monte Carlo checks
Z = 4.0

#: a plan of the 3-D stage's RRT (rounded): full speed past the first ball, a slower turn,
#: full speed past the box to the target; the executions' final tip is skewed across it
CLOSE_PASS = [[0.4, -8.0]] * 6 + [[0.218, 6.76]] * 6 + [[0.4, 4.8]] * 6 + [[0.4, -6.8]] * 5


def _skew(a: np.ndarray) -> np.ndarray:
    r = a - a.mean(axis=0)
    return (r**3).mean(axis=0) / r.var(axis=0) ** 1.5


@pytest.fixture(scope="module")
def close_pass():
    """The plan, its LQG controller and its second-order model."""
    sim = scenario_from_config("needle3d", None, "actuation")
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), np.array(CLOSE_PASS))
    ctrl = lqg_controller(linearize(sim, plan, n_samples=16, seed=0))
    W = np.array(sim.distribution.cov)
    return sim, plan, ctrl, second_order_model(sim, plan, ctrl, W), W


@pytest.fixture(scope="module")
def executions(close_pass):
    """600 closed-loop executions of the plan: success (collisions counted at every state,
    the run carried on past one so that every run ends) and the final tip relative to the
    deformed target centre."""
    sim, plan, ctrl, *_ = close_pass
    going_on = copy.copy(sim)
    going_on.in_collision = lambda state: False  # the same run, not stopped at a collision
    success, rel = [], []
    for s in spawn_seeds(1, 600):
        gen = np.random.default_rng(s)
        ex = execute(going_on, plan, ctrl, sim.sample_params(gen), seed=gen)
        hit = any(sim.in_collision(y) for y in ex.states[1:])
        success.append(ex.outcome == "success" and not hit)
        last = ex.states[-1]
        rel.append(last.pose[:3] - sim.goal(last).centre)
    return np.array(success), np.array(rel)


def test_material_step_batch_is_the_simulators_step(close_pass, tol):
    """``K(u) m`` in one batch against the simulator's compiled step, state by state."""
    sim, plan, *_ = close_pass
    gen = np.random.default_rng(0)
    lo, hi = sim.control_bounds[:, 0], sim.control_bounds[:, 1]
    U = lo + gen.random((plan.n_steps, 2)) * (hi - lo)
    got = sim.material_step_batch(np.array([y.material for y in plan.states[:-1]]), U)
    params = sim.nominal_params
    for t, u in enumerate(U):
        want = sim.step(plan.states[t], u, params).material
        np.testing.assert_allclose(got[t], want, **tol["float64_exact"])


def test_linear_step_gives_the_linear_gaussian_moments(close_pass, tol):
    """With the step linearised and no clip the particles are a linear-Gaussian recursion,
    ``ξ' = F ξ + (0, K_t Δ_t) + N(0, Q)`` (the second-order model's ``F`` and ``Q``, its
    mean input without the second-order term): sample moments against it."""
    sim, plan, ctrl, mo, W = close_pass
    np.testing.assert_array_equal(ctrl.model()[4][0], sim.sensing_cov)  # the same N
    n, p = 40_000, 12
    res = lqgmp_particles(sim, plan, ctrl, mo, W, n_particles=n, step="linear", clip=False, seed=5)
    mean, cov = res.mean, res.cov
    mu, S = np.zeros(2 * p), np.array(mo.P0)
    for t in range(plan.n_steps):
        c = np.zeros(2 * p)
        c[p:] = ctrl.K[t] @ mo.offset[t]
        mu = mo.F[t] @ mu + c
        S = mo.F[t] @ S @ mo.F[t].T + mo.Q[t]
        sd = np.sqrt(np.clip(np.diag(S), 0.0, None))
        atol = tol["float64_exact"]["atol"]  # components without spread: round-off only
        assert np.all(np.abs(mean[t + 1] - mu) <= Z * sd / math.sqrt(n) + atol)
        var = np.diag(cov[t + 1])
        assert np.all(np.abs(var - sd**2) <= Z * sd**2 * math.sqrt(2 / n) + atol)


@pytest.mark.slow
def test_exact_step_predicts_the_executions(close_pass, executions):
    """The exact step's ``P(success)`` inside the executions' z = 4 Wilson interval, and the
    final tip's skewness across the plan — non-zero in the executions, beyond what 600 runs
    can show by chance, zero for any Gaussian model — matched by the particles, and not by
    the particles whose step is linear in the control."""
    sim, plan, ctrl, mo, W = close_pass
    success, rel = executions
    k, n = int(np.count_nonzero(success)), success.shape[0]
    lo, hi = binomial_interval(k, n, confidence=math.erf(Z / math.sqrt(2)))
    res = lqgmp_particles(sim, plan, ctrl, mo, W, n_particles=40_000, seed=2)
    assert lo <= res.p_success <= hi
    ex_skew = _skew(rel)
    se = math.sqrt(6.0 / n)
    axis = int(np.argmax(np.abs(ex_skew)))
    assert abs(ex_skew[axis]) > Z * se  # the executions' tip is not Gaussian
    *_, prel = _run(sim, plan, ctrl, mo, W, 40_000, "exact", True, np.random.default_rng(3))
    assert abs(_skew(prel)[axis] - ex_skew[axis]) <= Z * se
    # the counterfactual on the same draws: the step linear in the control leaves it out
    *_, plin = _run(sim, plan, ctrl, mo, W, 40_000, "linear", True, np.random.default_rng(3))
    assert abs(_skew(plin)[axis] - ex_skew[axis]) > Z * se


def test_draws_stop_at_the_first_batch_that_meets_the_standard_error():
    """Bernoulli draws with a known ``p``: the loop stops at the first batch whose binomial
    standard error is at most the target (checked by replaying the batches), never earlier;
    the cap holds; the estimate lies within z = 4 of ``p``; ``None`` draws one batch."""
    for p_true, target in ((0.5, 0.01), (0.95, 0.004), (0.999, 0.004), (0.3, 0.002)):
        gen = np.random.default_rng(7)
        hits = []

        def run_batch(m, gen=gen, hits=hits, p_true=p_true):
            k = int(np.count_nonzero(gen.random(m) < p_true))
            hits.append((k, m))
            return k, m

        k, n, extras = draw_until(run_batch, 300, target, 10**6)
        assert extras == [m for _, m in hits] and n == sum(extras) and n % 300 == 0
        cum = np.cumsum(hits, axis=0)
        ses = [binomial_se(int(kk), int(nn)) for kk, nn in cum]
        assert ses[-1] <= target and all(se > target for se in ses[:-1])
        assert abs(k / n - p_true) <= Z * math.sqrt(p_true * (1 - p_true) / n)
    k, n, extras = draw_until(lambda m: (m // 2, m), 300, 1e-9, 1000)  # the cap, last batch cut
    assert (k, n, extras) == (500, 1000, [300, 300, 300, 100])
    assert draw_until(lambda m: (m, m), 300, None, 1234)[1:] == (1234, [1234])


def test_particles_to_a_standard_error(close_pass):
    """``p_se``: whole batches until the binomial standard error of ``P(success)`` meets
    it; the reported standard error is that one; without the moments they are NaN."""
    sim, plan, ctrl, mo, W = close_pass
    res = lqgmp_particles(
        sim, plan, ctrl, mo, W, n_particles=8000, seed=4, p_se=0.006, batch=500, keep_moments=False
    )
    n = res.n_goal_samples
    assert n % 500 == 0 and n <= 8000
    k = round(res.p_success * n)
    assert res.p_success_se == binomial_se(k, n) <= 0.006
    one = lqgmp_particles(sim, plan, ctrl, mo, W, seed=4, p_se=0.5, batch=500)
    assert one.n_goal_samples == 500  # met by the first batch
    assert np.isnan(res.mean[1:]).all() and np.isnan(res.cov[1:]).all()
    np.testing.assert_array_equal(res.cov[0], mo.P0)
    assert 0.0 <= res.p_success <= res.p_collision_free <= 1.0


def test_bad_input(close_pass):
    sim, plan, ctrl, mo, W = close_pass
    with pytest.raises(InvalidInputError, match="step"):
        lqgmp_particles(sim, plan, ctrl, mo, W, step="cubic")
    with pytest.raises(InvalidInputError, match="moments"):
        lqgmp_particles(sim, plan, ctrl, "second-order", W)
    with pytest.raises(InvalidInputError, match="actuation_cov"):
        lqgmp_particles(sim, plan, ctrl, mo, -W)
    with pytest.raises(InvalidInputError, match="n_particles"):
        lqgmp_particles(sim, plan, ctrl, mo, W, n_particles=0)
    with pytest.raises(InvalidInputError, match="p_se"):
        lqgmp_particles(sim, plan, ctrl, mo, W, p_se=0.0)
    with pytest.raises(InvalidInputError, match="batch"):
        lqgmp_particles(sim, plan, ctrl, mo, W, p_se=0.01, batch=0)
    with pytest.raises(InvalidInputError, match="world frame"):
        lqgmp_particles(sim.with_frame("material"), plan, ctrl, mo, W)
    with pytest.raises(InvalidInputError, match="material, controls"):
        sim.material_step_batch(np.zeros((2, 12)), np.zeros((3, 2)))
