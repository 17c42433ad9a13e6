"""3-D LQG-MP: nearest points of convex bodies (exact characterisation), and the three
estimates against closed forms of one Gaussian step (a half-space, a ball) and against each
other on the same linear-Gaussian model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ndtr
from scipy.stats import chi2, ncx2

from riskplan.control import NominalPlan
from riskplan.control.linearize import Linearization
from riskplan.control.lqg import LQGController
from riskplan.control.lqgmp import lqgmp
from riskplan.control.lqgmp3d import binomial_se, lqgmp_3d
from riskplan.errors import InvalidInputError
from riskplan.geometry3d import ConvexBody, nearest_to_origin
from riskplan.scenarios.base import SimParams


def _random_body(gen, kind):
    A = gen.standard_normal((3, 3)) * 0.3 + np.eye(3)
    return ConvexBody(kind, gen.uniform(-3, 3, 3), A)


@pytest.mark.parametrize("kind", ["ellipsoid", "box"])
def test_nearest_point_is_optimal(tol, kind):
    """y* on the body and the half-space nᵀy ≥ |y*| holding the body: exactly the nearest point."""
    gen = np.random.default_rng(0)
    for _ in range(20):
        b = _random_body(gen, kind)
        Lc = np.linalg.cholesky(np.cov(gen.standard_normal((3, 10))) + 0.1 * np.eye(3))
        mu = gen.standard_normal(3)
        d, n = nearest_to_origin(b, Lc, mu)
        a = np.linalg.solve(Lc, b.centre - mu)
        M = np.linalg.solve(Lc, b.A)
        if n is None:
            assert b.contains(mu)
            continue
        y = d * n
        s = np.linalg.solve(M, y - a)  # y's coordinates in the body
        gauge = np.linalg.norm(s) if kind == "ellipsoid" else np.abs(s).max()
        np.testing.assert_allclose(gauge, 1.0, **tol["closest_point"])
        assert b.support_min(n, a, M) >= d - tol["closest_point"]["atol"]
        # brute force: no sampled point of the body is nearer
        ss = gen.standard_normal((4000, 3))
        ss = ss / (
            np.linalg.norm(ss, axis=1, keepdims=True)
            if kind == "ellipsoid"
            else np.abs(ss).max(axis=1, keepdims=True)
        )
        assert np.linalg.norm(a + ss @ M.T, axis=1).min() >= d - tol["closest_point"]["atol"]


class _OneStep:
    """A fake 3-D simulator for one Gaussian step: x̄₁ ~ N(0, M), no feedback."""

    workspace_dim = 3
    goal_point_indices = (0, 1, 2)

    def __init__(self, bodies):
        self.bodies = bodies

    def obstacles(self, state):
        return self.bodies

    def goal(self, state):
        return ConvexBody("ellipsoid", np.zeros(3), 100.0 * np.eye(3))


def _one_step(M3):
    p, q, m = 12, 2, 3
    M = np.zeros((1, p, p))
    M[0, :3, :3] = M3
    lin = Linearization(
        A=np.eye(p)[None],
        B=np.zeros((1, p, q)),
        M=M,
        H=np.concatenate([np.eye(3), np.zeros((3, 9))], axis=1)[None],
        N=np.eye(m)[None],
        rank=np.zeros(1, dtype=np.int64),
    )
    ctrl = LQGController(
        L=np.zeros((1, q, p)),
        K=np.zeros((1, p, m)),
        P=np.zeros((1, p, p)),
        P0=np.zeros((p, p)),
        lin=lin,
    )
    plan = NominalPlan(
        states=(0, 1), controls=np.zeros((1, q)), reduced=np.zeros((2, p)), params=SimParams()
    )
    return plan, ctrl


def _binomial(p, n):
    return 4.0 * math.sqrt(max(p * (1 - p), 1e-4) / n)


def test_half_space_is_exact_for_truncation(tol):
    """A huge box whose near face is a plane at distance D: P(collision) = 1 − Φ(D/σ_n)."""
    M3 = np.array([[0.04, 0.01, 0.0], [0.01, 0.02, 0.0], [0.0, 0.0, 0.01]])
    D = 0.25
    box = ConvexBody("box", np.array([D + 100.0, 0, 0]), 100.0 * np.eye(3))
    plan, ctrl = _one_step(M3)
    sim = _OneStep([box])
    exact = float(ndtr(D / math.sqrt(M3[0, 0])))
    tr = lqgmp(sim, plan, ctrl, method="truncation", seed=0)
    np.testing.assert_allclose(tr.p_collision_free, exact, **tol["float64_ref"])
    n = 40000
    sa = lqgmp(sim, plan, ctrl, method="sampling", n_goal_samples=n, seed=1)
    assert abs(sa.p_collision_free - exact) <= _binomial(exact, n)
    sg = lqgmp(sim, plan, ctrl, method="sigma", seed=0)
    # sigma: the mass inside the c-sigma ellipsoid, c the whitened distance
    np.testing.assert_allclose(
        sg.p_collision_free, chi2(3).cdf((D / math.sqrt(M3[0, 0])) ** 2), **tol["float64_ref"]
    )
    assert sg.p_collision_free < tr.p_collision_free  # conservative


def test_ball_truncation_bounds_and_sampling_matches_closed_form():
    """Isotropic N(0, s² I) and a ball: P(collision) is a non-central χ²₃; the truncation's
    tangent half-space holds the ball, so its collision estimate is an upper bound; sampling
    matches within its binomial error."""
    s2, c, r = 0.01, np.array([0.25, 0.1, 0.0]), 0.12
    ball = ConvexBody("ellipsoid", c, r * np.eye(3))
    plan, ctrl = _one_step(s2 * np.eye(3))
    sim = _OneStep([ball])
    exact = 1.0 - float(ncx2(3, float(c @ c) / s2).cdf(r * r / s2))
    tr = lqgmp(sim, plan, ctrl, method="truncation", seed=0)
    n = 40000
    sa = lqgmp(sim, plan, ctrl, method="sampling", n_goal_samples=n, seed=1)
    assert tr.p_collision_free <= exact
    assert abs(sa.p_collision_free - exact) <= _binomial(exact, n)


def test_truncation_skips_an_obstacle_behind_a_chosen_half_space():
    """A second ball wholly behind the first one's tangent plane adds nothing."""
    plan, ctrl = _one_step(0.01 * np.eye(3))
    near = ConvexBody("ellipsoid", np.array([0.3, 0.0, 0.0]), 0.1 * np.eye(3))
    behind = ConvexBody("ellipsoid", np.array([0.6, 0.0, 0.0]), 0.1 * np.eye(3))
    one = lqgmp(_OneStep([near]), plan, ctrl, method="truncation", seed=0)
    two = lqgmp(_OneStep([near, behind]), plan, ctrl, method="truncation", seed=0)
    assert one.p_collision_free == two.p_collision_free


def test_mean_inside_an_obstacle_gives_zero():
    plan, ctrl = _one_step(0.01 * np.eye(3))
    ball = ConvexBody("ellipsoid", np.zeros(3), 0.1 * np.eye(3))
    for method in ("sigma", "truncation"):
        assert lqgmp(_OneStep([ball]), plan, ctrl, method=method, seed=0).p_collision_free == 0.0


class _MovingGoal(_OneStep):
    """A target ball of radius r at the origin whose centre follows the tip: c = α x."""

    def __init__(self, r, alpha):
        super().__init__([])
        self.r, self.alpha = r, alpha

    def goal(self, state):
        return ConvexBody("ellipsoid", np.zeros(3), self.r * np.eye(3))

    def goal_jacobian(self, state, params):
        J = np.zeros((3, 12))
        J[:, :3] = self.alpha * np.eye(3)
        return J


@pytest.mark.parametrize("alpha", [0.0, 0.3])
def test_goal_motion_tests_the_tip_against_the_moved_target(alpha):
    """With the target centre moving by α δx, the tip relative to it is (1 − α) δx:
    P(goal) = F_χ²₃(r² / ((1 − α)² s²)) for N(0, s² I) with ``goal_motion=True``; the
    default keeps the fixed target's F_χ²₃(r² / s²). Truncation (no obstacles) and sampling both draw it."""
    s2, r, n = 0.01, 0.15, 40000
    plan, ctrl = _one_step(s2 * np.eye(3))
    sim = _MovingGoal(r, alpha)
    exact = float(chi2(3).cdf(r * r / ((1 - alpha) ** 2 * s2)))
    fixed = float(chi2(3).cdf(r * r / s2))
    for method in ("truncation", "sampling"):
        got = lqgmp_3d(
            sim, plan, ctrl, method=method, n_goal_samples=n, seed=2, goal_motion=True
        ).p_goal
        assert abs(got - exact) <= _binomial(exact, n)
        off = lqgmp_3d(sim, plan, ctrl, method=method, n_goal_samples=n, seed=2)
        assert abs(off.p_goal - fixed) <= _binomial(fixed, n)


def test_goal_se_draws_batches_until_the_standard_error_is_met():
    """``goal_se``: the batch loop stops at the first batch whose standard error
    sqrt(p̃(1 − p̃)/n) is at most the target (one batch fewer is above it, on the same draws:
    the generator's stream does not depend on the batching); the estimate matches the closed
    form F_χ²₃(r²/s²) and a fixed 10⁶-draw estimate within their binomial errors (the draws
    are ``goal="draws"``; the default goal test is exact)."""
    s2, r, batch, target = 0.01, 0.3, 1000, 1e-3
    plan, ctrl = _one_step(s2 * np.eye(3))
    sim = _MovingGoal(r, 0.0)
    exact = float(chi2(3).cdf(r * r / s2))  # 0.97
    got = lqgmp_3d(
        sim,
        plan,
        ctrl,
        method="truncation",
        goal="draws",
        n_goal_samples=batch,
        goal_se=target,
        seed=5,
    )
    n = got.n_goal_samples
    assert n % batch == 0 and n > batch
    assert isinstance(got.p_success, float) and isinstance(got.p_success_se, float)
    same = lqgmp_3d(sim, plan, ctrl, method="truncation", goal="draws", n_goal_samples=n, seed=5)
    assert same.p_goal == got.p_goal  # the same draws, one batch
    k = round(got.p_goal * n)
    assert got.p_success_se == binomial_se(k, n) <= target
    fewer = lqgmp_3d(
        sim, plan, ctrl, method="truncation", goal="draws", n_goal_samples=n - batch, seed=5
    )
    assert binomial_se(round(fewer.p_goal * (n - batch)), n - batch) > target
    assert abs(got.p_goal - exact) <= _binomial(exact, n)
    big = 1_000_000
    ref = lqgmp_3d(sim, plan, ctrl, method="truncation", goal="draws", n_goal_samples=big, seed=6)
    assert abs(got.p_goal - ref.p_goal) <= _binomial(exact, n) + _binomial(exact, big)


def test_goal_se_is_capped_and_validated():
    plan, ctrl = _one_step(0.01 * np.eye(3))
    sim = _MovingGoal(0.3, 0.0)
    kw = dict(method="sigma", n_goal_samples=1000, seed=0, goal="draws")
    capped = lqgmp_3d(sim, plan, ctrl, goal_se=1e-6, max_goal_samples=2500, **kw)
    assert capped.n_goal_samples == 2500
    assert lqgmp_3d(sim, plan, ctrl, **kw).n_goal_samples == 1000  # no target: one batch
    sampled = lqgmp_3d(sim, plan, ctrl, method="sampling", n_goal_samples=500, seed=0)
    assert sampled.n_goal_samples == 500
    assert sampled.p_success_se == binomial_se(round(sampled.p_success * 500), 500)
    for bad in (0.0, -1e-3, float("nan"), "0.1"):
        with pytest.raises(InvalidInputError, match="goal_se"):
            lqgmp_3d(sim, plan, ctrl, goal_se=bad, **kw)
    with pytest.raises(InvalidInputError, match="goal_se"):
        lqgmp_3d(sim, plan, ctrl, method="sampling", goal_se=1e-3, n_goal_samples=10, seed=0)
