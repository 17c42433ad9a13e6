"""LQG-MP: a-priori covariances against Monte Carlo of closed-loop runs of the linear toy,
P(goal) against the success rate, the collision factor against a half-plane closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ndtr

from riskplan.control import (
    LQGController,
    NominalPlan,
    execute,
    lqg_controller,
    lqgmp,
    monte_carlo_success,
)
from riskplan.control.linearize import Linearization
from riskplan.errors import InvalidInputError
from riskplan.geometry3d import ConvexBody
from riskplan.scenarios.base import SimParams
from riskplan.scenarios.uncertainty import ActuationNoise
from tests.conftest import TOL

from .toy import LinearToy, square, toy_system

SIGMA_W = 0.1


def _exact(sim, T):
    Sw = SIGMA_W**2 * np.eye(sim.control_dim)
    H = sim.observation_matrix
    return Linearization(
        A=np.broadcast_to(sim.A_true, (T, 3, 3)),
        B=np.broadcast_to(sim.B_true, (T, 3, 3)),
        M=np.broadcast_to(sim.B_true @ Sw @ sim.B_true.T, (T, 3, 3)),
        H=np.broadcast_to(H, (T, 2, 3)),
        N=np.broadcast_to(sim.sensing_cov, (T, 2, 2)),
        rank=np.full(T, 3),
    )


def _toy(rng, T):
    A, B, _ = toy_system(rng, scale=0.2)
    sim = LinearToy(
        A,
        B,
        sensing_std=0.1,
        distribution=ActuationNoise(cov=tuple(map(tuple, SIGMA_W**2 * np.eye(3)))),
    )
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), rng.uniform(-0.5, 0.5, (T, 3)))
    return sim, plan


def test_joint_covariance_matches_monte_carlo(rng):
    T, n = 6, 600
    sim, plan = _toy(rng, T)
    xT = plan.reduced[-1]
    sim._goal = square(xT[0], xT[1], 10.0)
    ctrl = lqg_controller(_exact(sim, T), Q=10 * np.eye(3))
    res = lqgmp(sim, plan, ctrl, n_goal_samples=10)
    xi = np.empty((n, 6))
    for k in range(n):
        gen = np.random.default_rng(1000 + k)
        ex = execute(sim, plan, ctrl, sim.distribution.sample(gen), seed=gen, keep_states=False)
        xi[k, :3] = ex.x[-1] - plan.reduced[-1]
        xi[k, 3:] = ex.estimates[-1] - plan.reduced[-1]
    S = res.cov[T]
    w, v = np.linalg.eigh(S)
    keep = w > TOL["covariance_support"]["rtol"] * w.max()
    W = v[:, keep] / np.sqrt(w[keep])  # whitening of the support
    E = (xi @ W).T @ (xi @ W) / n  # ≈ I, entries with sd sqrt(2/n) (diagonal) and sqrt(1/n)
    sd = np.where(np.eye(keep.sum(), dtype=bool), math.sqrt(2 / n), math.sqrt(1 / n))
    assert np.all(np.abs(E - np.eye(keep.sum())) < 4.5 * sd), np.round(E, 3)
    # and nothing outside the support
    if (~keep).any():
        assert np.abs(xi @ v[:, ~keep]).max() < TOL["covariance_support"]["atol"]


def test_p_goal_matches_monte_carlo_success(rng):
    T = 5
    sim, plan = _toy(rng, T)
    xT = plan.reduced[-1]
    sim._goal = square(xT[0] + 0.05, xT[1], 0.2)
    ctrl = lqg_controller(_exact(sim, T))
    res = lqgmp(sim, plan, ctrl, n_goal_samples=40_000, seed=0)
    mc = monte_carlo_success(sim, plan, ctrl, sim.distribution, n=600, seed=4)
    assert res.p_collision_free == 1.0  # the toy has no obstacles here
    # LQG-MP's own sampling error is ~0.0025: widen the Wilson interval by 3 of it
    assert mc.low - 0.0075 <= res.p_goal <= mc.high + 0.0075, (res.p_goal, mc.low, mc.high)
    assert 0.1 < res.p_goal < 0.95


def test_half_plane_closed_form(rng):
    # one step, x_1 ~ N(x*_1, Σ), an obstacle whose near edge is the line x = x*_1 + d
    T = 1
    sim, plan = _toy(rng, T)
    x1 = plan.reduced[1]
    d = 0.15
    sim._obstacles = [
        np.array(
            [
                [x1[0] + d, x1[1] - 50],
                [x1[0] + d + 100, x1[1] - 50],
                [x1[0] + d + 100, x1[1] + 50],
                [x1[0] + d, x1[1] + 50],
            ]
        )
    ]
    sim._goal = square(x1[0], x1[1], 100.0)
    ctrl = lqg_controller(_exact(sim, T))
    trunc = lqgmp(sim, plan, ctrl, method="truncation", n_goal_samples=10)
    sigma = lqgmp(sim, plan, ctrl, method="sigma", n_goal_samples=10)
    sx = math.sqrt(sigma.cov[1, 0, 0])  # before truncation
    exact_free = float(ndtr(d / sx))
    np.testing.assert_allclose(trunc.p_collision_free, exact_free, **TOL["half_plane_truncation"])
    np.testing.assert_allclose(
        sigma.p_collision_free, -math.expm1(-0.5 * (d / sx) ** 2), **TOL["half_plane_sigma"]
    )
    assert sigma.p_collision_free < exact_free  # the chi-square ball is conservative
    # truncation removes the mass beyond the line: the mean moves away from it
    assert trunc.mean[1, 0] < 0 and trunc.cov[1, 0, 0] < sx**2


def test_mean_in_obstacle_gives_zero(rng):
    sim, plan = _toy(rng, 3)
    x2 = plan.reduced[2]
    sim._obstacles = [square(x2[0], x2[1], 0.01)]
    sim._goal = square(0, 0, 100.0)
    ctrl = lqg_controller(_exact(sim, 3))
    for m in ("sigma", "truncation"):
        r = lqgmp(sim, plan, ctrl, method=m, n_goal_samples=10)
        assert r.p_free_steps[1] == 0.0 and r.p_success == 0.0


def test_bad_input(rng):
    sim, plan = _toy(rng, 2)
    sim._goal = square(0, 0, 1.0)
    ctrl = lqg_controller(_exact(sim, 2))
    with pytest.raises(InvalidInputError, match="method"):
        lqgmp(sim, plan, ctrl, method="exact")
    with pytest.raises(InvalidInputError, match="controller"):
        lqgmp(sim, plan, lqg_controller(_exact(sim, 1)))
    with pytest.raises(
        InvalidInputError, match=r"goal_motion: options of the 3-D model \(workspace_dim = 3\) only"
    ):
        lqgmp(sim, plan, ctrl, goal_motion=True)


def test_sigma_distances_batch_equals_free_region(rng, tol):
    # the vectorised σ-distance is the first half-space of the Patil construction
    from riskplan.collision import free_region, precision_cholesky_from_covariance
    from riskplan.control.lqgmp import _edges, polygon_environment, sigma_distances
    from riskplan.scenarios.needle import NeedleScenario

    sim = NeedleScenario()
    s = sim.initial_state()
    polys = sim.obstacles(s)
    env = polygon_environment(polys)
    a, b = _edges(polys)
    pts = rng.uniform(0, 1, (40, 2))
    L = rng.normal(0, 0.05, (40, 2, 2))
    covs = L @ np.swapaxes(L, 1, 2) + 1e-4 * np.eye(2)
    c, inside = sigma_distances(a, b, pts, covs)
    np.testing.assert_array_equal(inside, env.contains(pts))
    for k in np.flatnonzero(~inside):
        fr = free_region(pts[k], precision_cholesky_from_covariance(covs[k]), env, cutoff=np.inf)
        np.testing.assert_allclose(c[k], fr.distances.min(), **tol["float64_ref"])


def test_sigma_vectorised_equals_loop(rng):
    # obstacle polygons that change size along the plan force the per-step loop
    sim, plan = _toy(rng, 4)
    x2 = plan.reduced[2]
    sim._goal = square(0, 0, 100.0)
    sim._obstacles = [square(x2[0] + 0.3, x2[1], 0.1)]
    ctrl = lqg_controller(_exact(sim, 4))
    fast = lqgmp(sim, plan, ctrl, n_goal_samples=10)
    calls = {"n": 0}
    base = sim.obstacles

    def changing(state=None):
        calls["n"] += 1
        return base() if calls["n"] % 2 else [np.vstack([o, o[:1] + [0.0, 1e-3]]) for o in base()]

    sim.obstacles = changing
    loop = lqgmp(sim, plan, ctrl, n_goal_samples=10)
    assert np.any((fast.p_free_steps > 0) & (fast.p_free_steps < 1))
    np.testing.assert_allclose(loop.p_free_steps, fast.p_free_steps, **TOL["float64_accumulated"])


def test_manipulation_points_and_methods():
    # the manipulation scenario checks its 12 sensed boundary points and its target
    import warnings

    from riskplan.control import linearize
    from riskplan.control.lqgmp import point_indices
    from riskplan.scenarios.manipulation import ManipulationScenario

    sim = ManipulationScenario()
    col, goal = point_indices(sim)
    assert col.shape == (12, 2) and tuple(goal) == (0, 1) and col.max() == 2 * sim.n_points - 1
    plan = NominalPlan.from_rollout(
        sim, sim.initial_state(), np.tile([0.2, 0.0, 0.0, -0.2, 0.1, 0.0], (3, 1))
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lin = linearize(sim, plan, n_a_runs=4, n_samples=0, seed=0)
    ctrl = lqg_controller(lin)
    for m in ("sigma", "truncation", "sampling"):
        r = lqgmp(sim, plan, ctrl, method=m, n_goal_samples=200, seed=0)
        assert (
            r.cov.shape == (4, 2 * sim.state_dim, 2 * sim.state_dim) and 0.0 <= r.p_success <= 1.0
        )
        assert r.p_goal == 0.0  # three small pushes do not bring the target into the goal disk


def test_polygon_environment_equals_validated_constructor(rng):
    from riskplan.collision import Environment
    from riskplan.control.lqgmp import polygon_environment

    polys = [
        square(0.2, 0.2, 0.1),
        square(0.7, 0.5, 0.05)[::-1],
    ]  # one counter-clockwise, one clockwise
    a, b = polygon_environment(polys), Environment.from_polygons(polys)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    pts = rng.uniform(0, 1, (200, 2))
    np.testing.assert_array_equal(a.contains(pts), b.contains(pts))


def test_drift_mean_matches_monte_carlo(rng):
    # force_scale ~ U[0.5, 2.5]: the toy's parameter term c (f - 1) has mean 0.5 c every step
    from riskplan.control import linearize
    from riskplan.scenarios.uncertainty import InteractionForceUncertainty

    A, B, c = toy_system(rng, scale=0.1)
    dist = InteractionForceUncertainty(low=0.5, high=2.5)
    sim = LinearToy(A, B, c, distribution=dist)
    T = 5
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), rng.uniform(-0.5, 0.5, (T, 3)))
    sim._goal = square(0, 0, 100.0)
    lin = linearize(sim, plan, dist, n_samples=4000, seed=0)
    np.testing.assert_allclose(
        lin.drift,
        np.broadcast_to(0.5 * c, (T, 3)),
        rtol=0,
        atol=TOL["monte_carlo_mean"]["atol"] * np.abs(c).max(),
    )
    ctrl = lqg_controller(lin)
    res = lqgmp(sim, plan, ctrl, drift=True, n_goal_samples=10)
    assert not np.any(
        lqgmp(sim, plan, ctrl, n_goal_samples=10).mean
    )  # the paper's model: zero mean
    n = 400
    xi = np.empty((n, 6))
    for k in range(n):
        gen = np.random.default_rng(k)
        ex = execute(sim, plan, ctrl, dist.sample(gen), seed=gen, keep_states=False)
        xi[k] = np.concatenate([ex.x[-1], ex.estimates[-1]]) - np.tile(plan.reduced[-1], 2)
    se = xi.std(axis=0) / math.sqrt(n)
    # the model mean uses the estimated drift (4000 draws): allow its error too
    assert np.all(np.abs(xi.mean(axis=0) - res.mean[T]) < 4.5 * se + 0.05 * np.abs(res.mean[T])), (
        xi.mean(0),
        res.mean[T],
    )


def _wall(x_edge, y_lo, y_hi):
    """A rectangle whose near (left) edge is the line x = x_edge for y in [y_lo, y_hi]."""
    return np.array([[x_edge, y_lo], [x_edge + 100, y_lo], [x_edge + 100, y_hi], [x_edge, y_hi]])


def test_persistent_deviation_along_a_wall_closed_form():
    # A = B = I, no feedback, noise in the first step only: x̄_t = m_0 for every t >= 1, so
    # the T steps along a wall at distance d are one event, P(no collision) = Φ(d/σ) exactly.
    # The sigma estimate multiplies T ellipse factors (1 − exp(−d²/2σ²))^T instead.
    from riskplan.control.lqg import LQGController

    T, sd, d = 10, 0.1, 0.1
    sim = LinearToy(np.eye(3), np.eye(3), sensing_std=0.1)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), np.tile([0.0, 0.1, 0.0], (T, 1)))
    sim._obstacles = [_wall(d, -10.0, 10.0)]
    sim._goal = square(0.0, 1.0, 100.0)
    M = np.zeros((T, 3, 3))
    M[0] = sd**2 * np.eye(3)
    lin = Linearization(
        A=np.broadcast_to(np.eye(3), (T, 3, 3)),
        B=np.broadcast_to(np.eye(3), (T, 3, 3)),
        M=M,
        H=np.broadcast_to(sim.observation_matrix, (T, 2, 3)),
        N=np.broadcast_to(sim.sensing_cov, (T, 2, 2)),
        rank=np.full(T, 3),
    )
    zeros = np.zeros
    ctrl = LQGController(
        L=zeros((T, 3, 3)), K=zeros((T, 3, 2)), P=zeros((T, 3, 3)), P0=zeros((3, 3)), lin=lin
    )
    exact = float(ndtr(d / sd))  # 0.841
    n = 40_000
    smp = lqgmp(sim, plan, ctrl, method="sampling", n_goal_samples=n, seed=0)
    se = math.sqrt(exact * (1 - exact) / n)
    assert abs(smp.p_success - exact) < 4.5 * se, (smp.p_success, exact)
    assert smp.p_goal == 1.0 and smp.p_free_steps[1:].min() == 1.0  # nothing new after step 1
    sig = lqgmp(sim, plan, ctrl, method="sigma", n_goal_samples=10)
    np.testing.assert_allclose(
        sig.p_success, (-math.expm1(-0.5 * (d / sd) ** 2)) ** T, **TOL["half_plane_sigma"]
    )
    assert sig.p_success < 0.02  # 0.39^10: the estimator, not the model, loses the plan
    trunc = lqgmp(sim, plan, ctrl, method="truncation", n_goal_samples=10)
    # the first step is exact; the moment-matched Gaussian of the survivors has a tail
    # beyond the line again, which each later step counts anew (0.73 here against 0.84)
    np.testing.assert_allclose(trunc.p_free_steps[0], exact, **TOL["half_plane_truncation"])
    assert np.all(trunc.p_free_steps[1:] < 1.0)
    assert sig.p_success < trunc.p_success < exact


def test_sampling_matches_closed_loop_of_the_linear_system(rng):
    # The decisive check of LQG-MP: on a linear system with Gaussian noise (the toy with
    # actuation noise, its exact linearisation, the LQG controller), executions *are* the
    # linear-Gaussian model. A path along a wall close to the controlled spread, with
    # correlated steps (A = I): "sampling" must agree with the executions within Monte
    # Carlo error (about 0.45 both); the sigma estimate is conservative (a lower bound per
    # step) and here far below them (0.001), which is why it must not be read as a
    # probability (truncation: 0.39).
    T = 8
    sim = LinearToy(
        np.eye(3),
        np.eye(3),
        sensing_std=0.05,
        distribution=ActuationNoise(cov=tuple(map(tuple, SIGMA_W**2 * np.eye(3)))),
    )
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), np.tile([0.0, 0.1, 0.0], (T, 1)))
    sim._obstacles = [_wall(0.12, 0.15, 0.85)]  # beside steps 2..8
    sim._goal = square(0.0, 0.8, 0.3)
    ctrl = lqg_controller(_exact(sim, T))
    n_mc, n_s = 2000, 40_000
    mc = monte_carlo_success(sim, plan, ctrl, sim.distribution, n=n_mc, seed=3)
    smp = lqgmp(sim, plan, ctrl, method="sampling", n_goal_samples=n_s, seed=0)
    p = mc.probability
    se = math.sqrt(p * (1 - p) * (1 / n_mc + 1 / n_s))
    assert 0.2 < p < 0.9, p  # the wall matters
    assert abs(smp.p_success - p) < 4.5 * se, (smp.p_success, p, se)
    np.testing.assert_allclose(
        np.prod(smp.p_free_steps), smp.p_collision_free, **TOL["float64_exact_rel"]
    )
    sig = lqgmp(sim, plan, ctrl, method="sigma", n_goal_samples=n_s, seed=0)
    # union bound on the per-step ellipse factors: a rigorous lower bound of P(no collision)
    assert 1.0 - np.sum(1.0 - sig.p_free_steps) <= smp.p_collision_free
    assert sig.p_success < mc.low, (sig.p_success, mc.low)


class _TwoPointBody(LinearToy):
    """x = (P0, P1): a rigid-free 'body' whose edge P0 → P1 is part of it; collision of the
    true simulator = the segment meets an obstacle (the points alone are not the body)."""

    collision_point_indices = ((0, 1), (2, 3))

    def in_collision(self, state):
        from riskplan.geometry2d import segments_intersect

        ring = np.array([state.x[:2], state.x[2:]])
        return any(
            bool(segments_intersect(ring[:1], ring[1:], o, np.roll(o, -1, axis=0)).any())
            for o in self._obstacles
        )


def _two_point(T, obstacle, sigma_w, with_outline):
    sim = _TwoPointBody(
        np.eye(4),
        np.eye(4),
        H=np.eye(4),
        sensing_std=0.005,
        x0=np.array([0.0, 0.0, 1.0, 0.0]),
        obstacles=[obstacle],
        goal=square(0.0, 0.0, 10.0),
        distribution=ActuationNoise(cov=tuple(map(tuple, sigma_w**2 * np.eye(4)))),
    )
    if with_outline:
        # the body is the segment P0 P1: its two end points, each moving with its own point
        sim.collision_outline = lambda state: (
            np.array([state.x[:2], state.x[2:]]),
            np.array([0, 1]),
            np.array([0, 1]),
            np.zeros(2),
        )
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), np.zeros((T, 4)))
    Sw = sigma_w**2 * np.eye(4)
    lin = Linearization(
        A=np.broadcast_to(np.eye(4), (T, 4, 4)),
        B=np.broadcast_to(np.eye(4), (T, 4, 4)),
        M=np.broadcast_to(Sw, (T, 4, 4)),
        H=np.broadcast_to(np.eye(4), (T, 4, 4)),
        N=np.broadcast_to(sim.sensing_cov, (T, 4, 4)),
        rank=np.full(T, 4),
    )
    return sim, plan, lqg_controller(lin)


def test_edge_through_an_obstacle_is_not_free():
    # two points 0.45 (45 sd) either side of a thin obstacle: the points alone are safe,
    # the edge between them crosses it
    wall = square(0.5, 0.0, 0.05)
    for with_outline in (False, True):
        sim, plan, ctrl = _two_point(3, wall, 0.01, with_outline)
        for m in ("sigma", "truncation", "sampling"):
            r = lqgmp(sim, plan, ctrl, method=m, n_goal_samples=500, seed=0)
            if with_outline:
                assert r.p_collision_free == 0.0 and r.p_success == 0.0, (m, r.p_success)
            else:  # what the points alone say (the defect the outline removes)
                assert r.p_collision_free > 0.99, (m, r.p_collision_free)
    mc = monte_carlo_success(sim, plan, ctrl, sim.distribution, n=20, seed=0)
    assert mc.successes == 0


def test_outline_sampling_matches_closed_loop_segment_collisions():
    # an obstacle just above the edge's middle: P(collision) is intermediate, and only the
    # edge can touch it (the points stay ~0.4 away)
    T = 3
    sim, plan, ctrl = _two_point(T, square(0.5, 0.05 + 0.01, 0.05), 0.01, True)
    res = lqgmp(sim, plan, ctrl, method="sampling", n_goal_samples=4000, seed=1)
    mc = monte_carlo_success(sim, plan, ctrl, sim.distribution, n=600, seed=2)
    assert 0.1 < res.p_success < 0.9, res.p_success
    # the sampling estimate's own error is <= 0.5/sqrt(4000) ~ 0.008: widen by 3 of it
    assert mc.low - 0.024 <= res.p_success <= mc.high + 0.024, (res.p_success, mc.low, mc.high)
    sig = lqgmp(sim, plan, ctrl, method="sigma", n_goal_samples=10)
    assert sig.p_success < res.p_success  # sigma stays conservative on the outline too


def test_outline_sigma_vectorised_equals_loop(monkeypatch):
    import importlib

    mod = importlib.import_module("riskplan.control.lqgmp")
    sim, plan, ctrl = _two_point(3, square(0.5, 0.05 + 0.01, 0.05), 0.01, True)
    fast = lqgmp(sim, plan, ctrl, n_goal_samples=10)
    monkeypatch.setattr(mod, "_sigma_free", lambda *a: None)
    loop = lqgmp(sim, plan, ctrl, n_goal_samples=10)
    assert np.all((fast.p_free_steps > 0) & (fast.p_free_steps < 1))
    np.testing.assert_allclose(loop.p_free_steps, fast.p_free_steps, **TOL["float64_accumulated"])


def test_overflow_propagates_from_the_gains_and_the_propagation(rng):
    """LQG-MP and execution get their gains from lqg_controller, which raises the recursion's
    NumericalError; finite gains whose closed loop overflows the covariance propagation raise
    one too (naming the step), never a NaN probability."""
    from riskplan.control.lqg import LQGController
    from riskplan.errors import NumericalError

    T = 4
    sim, plan = _toy(rng, T)
    lin = _exact(sim, T)
    huge = Linearization(
        A=np.broadcast_to(1e200 * np.eye(3), (T, 3, 3)),
        B=lin.B,
        M=lin.M,
        H=lin.H,
        N=lin.N,
        rank=lin.rank,
    )
    with pytest.raises(NumericalError, match="step"):
        lqg_controller(huge)
    # zero gains, A = 1e120 I: the covariance reaches 1e240·M at step 1, overflows at step 2
    big = Linearization(
        A=np.broadcast_to(1e120 * np.eye(3), (T, 3, 3)),
        B=lin.B,
        M=lin.M,
        H=lin.H,
        N=lin.N,
        rank=lin.rank,
    )
    ctrl = LQGController(
        L=np.zeros((T, 3, 3)),
        K=np.zeros((T, 3, 2)),
        P=np.zeros((T, 3, 3)),
        P0=np.zeros((3, 3)),
        lin=big,
    )
    for method in ("sigma", "truncation"):
        with pytest.raises(NumericalError) as exc:
            lqgmp(sim, plan, ctrl, method=method, n_goal_samples=10)
        assert exc.value.step == 2


@pytest.mark.parametrize("method", ["sigma", "truncation"])
def test_near_singular_point_covariance_on_the_per_step_path(method, monkeypatch):
    # A persistent deviation along x only (a rank-1 spread, as 2 parameter draws of a
    # large state can leave): the per-step path (taken when polygon sizes change along a
    # plan) must treat the near-singular 2 × 2 covariance as the vectorised path does, not
    # fail its Cholesky factor ("covariance: not positive definite") and lose the plan.
    import importlib

    from riskplan.control.lqg import LQGController

    mod = importlib.import_module("riskplan.control.lqgmp")  # the module, not the function
    T, sd, d = 6, 0.1, 0.1
    sim = LinearToy(np.eye(3), np.eye(3), sensing_std=0.1)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), np.tile([0.0, 0.1, 0.0], (T, 1)))
    sim._obstacles = [_wall(d, -10.0, 10.0)]
    sim._goal = square(0.0, 1.0, 100.0)
    v = np.array([1.0, 1e-9, 0.0])  # variance 1e-20 across: above 1e-24, far below 1e-12 of 1e-2
    M = np.zeros((T, 3, 3))
    M[0] = sd**2 * np.outer(v, v)
    lin = Linearization(
        A=np.broadcast_to(np.eye(3), (T, 3, 3)),
        B=np.broadcast_to(np.eye(3), (T, 3, 3)),
        M=M,
        H=np.broadcast_to(sim.observation_matrix, (T, 2, 3)),
        N=np.broadcast_to(sim.sensing_cov, (T, 2, 2)),
        rank=np.full(T, 3),
    )
    zeros = np.zeros
    ctrl = LQGController(
        L=zeros((T, 3, 3)), K=zeros((T, 3, 2)), P=zeros((T, 3, 3)), P0=zeros((3, 3)), lin=lin
    )
    fast = lqgmp(sim, plan, ctrl, method="sigma", n_goal_samples=10)
    monkeypatch.setattr(mod, "_sigma_free", lambda *a, **k: None)
    slow = lqgmp(sim, plan, ctrl, method=method, n_goal_samples=10)
    if method == "sigma":
        np.testing.assert_allclose(slow.p_free_steps, fast.p_free_steps, **TOL["float64_exact"])
        np.testing.assert_allclose(
            slow.p_success, (-math.expm1(-0.5 * (d / sd) ** 2)) ** T, **TOL["sigma_jitter"]
        )
    else:
        # the first step is the half-plane's exact Φ(d/σ)
        np.testing.assert_allclose(
            slow.p_free_steps[0], float(ndtr(d / sd)), **TOL["half_plane_truncation"]
        )


class _Moving3D:
    """A 3-D simulator for one step ``x̄₁ ~ N(0, s² I)`` of a 12-dimensional state (no
    feedback): a ball obstacle beside the path and a target ball whose centre follows the
    tip, ``c = α δx`` (``goal_jacobian``)."""

    workspace_dim = 3
    goal_point_indices = (0, 1, 2)

    def obstacles(self, state):
        return [ConvexBody("ellipsoid", np.array([0.35, 0.0, 0.0]), 0.1 * np.eye(3))]

    def goal(self, state):
        return ConvexBody("ellipsoid", np.zeros(3), 0.15 * np.eye(3))

    def goal_jacobian(self, state, params):
        J = np.zeros((3, 12))
        J[:, :3] = 0.3 * np.eye(3)
        return J


def _one_step_3d(s2):
    p, q, m = 12, 2, 3
    M = np.zeros((1, p, p))
    M[0, :3, :3] = s2 * np.eye(3)
    H = np.concatenate([np.eye(3), np.zeros((3, 9))], axis=1)[None]
    lin = Linearization(
        A=np.eye(p)[None],
        B=np.zeros((1, p, q)),
        M=M,
        H=H,
        N=np.eye(m)[None],
        rank=np.zeros(1, dtype=np.int64),
    )
    zeros = np.zeros((1, p, p))
    ctrl = LQGController(
        L=np.zeros((1, q, p)), K=np.zeros((1, p, m)), P=zeros, P0=zeros[0], lin=lin
    )
    plan = NominalPlan(
        states=(0, 1), controls=np.zeros((1, q)), reduced=np.zeros((2, p)), params=SimParams()
    )
    return plan, ctrl


@pytest.mark.parametrize("method", ["sigma", "truncation", "sampling"])
def test_dispatcher_hands_the_3d_options_to_lqgmp_3d(method):
    """``lqgmp`` on a 3-D simulator is ``lqgmp_3d`` with every keyword, the 3-D model's own
    (``goal_motion``, ``goal_se``) included: the same draws give the same result; without
    ``goal_motion`` the fixed target gives another ``P(goal)`` (the option is not dropped)."""
    from riskplan.control.lqgmp3d import lqgmp_3d

    plan, ctrl = _one_step_3d(0.01)
    sim = _Moving3D()
    kw = dict(method=method, n_goal_samples=4000, seed=3, goal_motion=True)
    if method != "sampling":
        kw |= dict(goal_se=0.01, max_goal_samples=20_000)
    via = lqgmp(sim, plan, ctrl, **kw)
    direct = lqgmp_3d(sim, plan, ctrl, **kw)
    assert via.p_success == direct.p_success and via.p_goal == direct.p_goal
    assert via.p_collision_free == direct.p_collision_free
    fixed = lqgmp(sim, plan, ctrl, method=method, n_goal_samples=4000, seed=3)
    assert fixed.p_goal != via.p_goal
