"""LQG execution on the true simulator and its Monte Carlo success rate."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.control import NominalPlan, execute, linearize, lqg_controller, monte_carlo_success
from riskplan.errors import InvalidInputError
from riskplan.scenarios.uncertainty import ActuationNoise

from .toy import LinearToy, square, toy_system


def _setup(rng, T=6, goal_half=0.3):
    A, B, _ = toy_system(rng, scale=0.1)
    sim = LinearToy(A, B, distribution=ActuationNoise(cov=tuple(map(tuple, 0.01 * np.eye(3)))))
    u = rng.uniform(-0.5, 0.5, (T, 3))
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    xT = plan.reduced[-1]
    sim._goal = square(xT[0], xT[1], goal_half)
    return sim, plan


def test_open_loop_nominal_reproduces_plan(rng):
    sim, plan = _setup(rng)
    ex = execute(sim, plan, None, plan.params, seed=0)
    np.testing.assert_array_equal(ex.x, plan.reduced)
    assert ex.success and not ex.collided


def test_closed_loop_without_noise_stays_on_plan(rng, tol):
    # no actuation noise and (almost) no sensing noise: the estimate stays ~0, so does the feedback
    sim, plan = _setup(rng)
    sim.sensing_cov = 1e-10 * np.eye(2)
    lin = linearize(sim, plan, seed=0)
    ex = execute(sim, plan, lqg_controller(lin), plan.params, seed=0)
    np.testing.assert_allclose(ex.x, plan.reduced, **tol["noise_free_tracking"])
    np.testing.assert_allclose(ex.estimates, plan.reduced, **tol["noise_free_tracking"])


def test_feedback_shrinks_final_spread(rng):
    sim, plan = _setup(rng, T=10)
    lin = linearize(sim, plan, sim.distribution, n_samples=64, seed=1)
    ctrl = lqg_controller(lin, Q=100 * np.eye(3), R=np.eye(3))
    finals = {}
    for name, c in (("open", None), ("closed", ctrl)):
        xs = []
        for k in range(150):
            gen = np.random.default_rng(k)
            ex = execute(sim, plan, c, sim.distribution.sample(gen), seed=gen, keep_states=False)
            xs.append(ex.x[-1] - plan.reduced[-1])
        finals[name] = np.mean(np.sum(np.square(xs), axis=1))
    assert finals["closed"] < 0.5 * finals["open"]


def test_monte_carlo_success_backends_and_interval(rng):
    sim, plan = _setup(rng, goal_half=0.05)
    lin = linearize(sim, plan, sim.distribution, n_samples=32, seed=2)
    ctrl = lqg_controller(lin)
    a = monte_carlo_success(sim, plan, ctrl, sim.distribution, n=30, seed=3)
    b = monte_carlo_success(
        sim, plan, ctrl, sim.distribution, n=30, seed=3, backend="local", workers=2
    )
    np.testing.assert_array_equal(a.success, b.success)
    assert 0 < a.successes < 30  # the goal is tight enough for some runs to miss
    assert a.low <= a.probability <= a.high and a.success.shape == (30,)
    with pytest.raises(InvalidInputError, match="n"):
        monte_carlo_success(sim, plan, ctrl, n=0)


def test_collision_stops_the_run(rng):
    sim, plan = _setup(rng)
    x3 = plan.reduced[3]
    sim._obstacles = [square(x3[0], x3[1], 1e-3)]
    ex = execute(sim, plan, None, plan.params)
    assert ex.collided and ex.failed_step == 3 and not ex.success and len(ex.x) == 4


def test_outcomes_carry_their_reasons(rng):
    """Each run ends in one outcome with its reason: a solver that fails or returns a
    non-finite state is a solver failure (never a collision or a success), leaving the
    body (``inside``) is its own failure, and the counts add up in the Monte Carlo."""
    from riskplan.control.lqg import OUTCOMES
    from riskplan.errors import ElementInversionError

    sim, plan = _setup(rng)
    base = execute(sim, plan, None, plan.params)
    assert base.outcome == "success" and base.reason is None
    x3 = plan.reduced[3]
    sim._obstacles = [square(x3[0], x3[1], 1e-3)]
    hit = execute(sim, plan, None, plan.params)
    assert hit.outcome == "collision" and "step 3" in hit.reason
    sim._obstacles = []

    class Inverting(LinearToy):
        def step(self, state, control, params=None):
            if state.t == 2:
                raise ElementInversionError("element 7 inverted (det F = -0.1)")
            return super().step(state, control, params)

    def Diverging(A, B, distribution):
        return LinearToy(A, B, distribution=distribution, nan_at=4)

    class Leaving(LinearToy):
        def inside(self, state):
            return state.t < 5

    for cls, outcome, words, step in (
        (Inverting, "solver_failure", "element 7 inverted", 2),
        (Diverging, "solver_failure", "non-finite", 3),
        (Leaving, "left_tissue", "left the body at step 5", 5),
    ):
        other = cls(sim.A_true, sim.B_true, distribution=sim.distribution)
        other._goal = sim._goal
        ex = execute(other, plan, None, plan.params)
        assert ex.outcome == outcome and words in ex.reason and ex.failed_step == step
        assert not ex.success and not ex.collided
        mc = monte_carlo_success(other, plan, None, other.distribution, n=4, seed=0)
        assert mc.outcomes[outcome] == 4 and mc.successes == 0 and not mc.collided.any()
        assert sum(mc.outcomes.values()) == 4 and set(mc.outcomes) == set(OUTCOMES)
        assert len(mc.solver_errors) == (4 if outcome == "solver_failure" else 0)
    sim._goal = square(100.0, 100.0, 1e-3)
    miss = execute(sim, plan, None, plan.params)
    assert miss.outcome == "missed_goal" and miss.reason == "not in the goal at the end"


def test_goal_at_any_stops_at_the_first_goal_state(rng):
    # the goal sits around x*_3: the plan passes through it and leaves
    sim, plan = _setup(rng)
    x3 = plan.reduced[3]
    sim._goal = square(x3[0], x3[1], 1e-3)
    final = execute(sim, plan, None, plan.params)
    assert not final.success and len(final.x) == plan.n_steps + 1
    anyg = execute(sim, plan, None, plan.params, goal_at="any")
    assert anyg.success and len(anyg.x) == 4
    mc = monte_carlo_success(sim, plan, None, "nominal", n=3, seed=0, goal_at="any")
    assert mc.successes == 3
    with pytest.raises(InvalidInputError, match="goal_at"):
        execute(sim, plan, None, plan.params, goal_at="first")
    with pytest.raises(InvalidInputError, match="goal_at"):
        monte_carlo_success(sim, plan, None, n=3, goal_at="first")


def test_memoryless_system_gets_no_feedback(rng, tol):
    # x_{t+1} = B u_t + noise (no memory of x_t, like the manipulation scenario's
    # quasi-static equilibria): the linearisation finds A_t = 0, and the LQR gain
    # L_t = −(R + Bᵀ P B)⁻¹ Bᵀ P A_t is zero. The loop runs (the filter's estimate moves
    # with the measurements) but applies u*_t, so every execution equals the open-loop one
    # with the same draws: the Fig. 6 "ours without selection" = "RRT" equality.
    _, B, _ = toy_system(rng)
    sim = LinearToy(
        np.zeros((3, 3)), B, distribution=ActuationNoise(cov=tuple(map(tuple, 0.01 * np.eye(3))))
    )
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), rng.uniform(-0.5, 0.5, (5, 3)))
    sim._goal = square(*plan.reduced[-1, :2], 0.2)
    lin = linearize(sim, plan, sim.distribution, n_samples=32, seed=0)
    np.testing.assert_allclose(lin.A, 0.0, **tol["float64_abs"])
    ctrl = lqg_controller(lin)
    np.testing.assert_allclose(ctrl.L, 0.0, **tol["float64_abs"])
    moved = 0.0
    for k in range(10):
        runs = []
        for c in (None, ctrl):
            gen = np.random.default_rng(k)
            runs.append(execute(sim, plan, c, sim.distribution.sample(gen), seed=gen))
        np.testing.assert_allclose(runs[1].controls, plan.controls, **tol["float64_abs"])
        np.testing.assert_allclose(runs[1].x, runs[0].x, **tol["float64_abs"])
        moved = max(moved, float(np.abs(runs[1].estimates - plan.reduced).max()))
    assert moved > 0.01  # the estimate did follow the deviations
    # with memory (A = I) the same construction does feed back
    sim_m = LinearToy(np.eye(3), B, distribution=sim.distribution)
    plan_m = NominalPlan.from_rollout(sim_m, sim_m.initial_state(), plan.controls)
    lin_m = linearize(sim_m, plan_m, sim_m.distribution, n_samples=32, seed=0)
    assert np.abs(lqg_controller(lin_m).L).max() > 0.1


def test_monte_carlo_none_means_the_simulators_distribution(rng):
    # one rule with linearize and the selection: None reads sim.distribution; "nominal"
    # runs every execution on the nominal parameters
    sim, plan = _setup(rng, goal_half=0.05)
    none = monte_carlo_success(sim, plan, None, None, n=40, seed=5)
    dist = monte_carlo_success(sim, plan, None, sim.distribution, n=40, seed=5)
    nominal = monte_carlo_success(sim, plan, None, "nominal", n=40, seed=5)
    np.testing.assert_array_equal(none.success, dist.success)
    assert nominal.successes == 40  # open loop on the nominal parameters is the plan
    assert none.successes < 40  # the actuation noise moves some runs out of the goal
    with pytest.raises(InvalidInputError, match="nominal"):
        monte_carlo_success(sim, plan, None, "nominl", n=3)
