"""The exact goal test of the 3-D LQG-MP (:mod:`riskplan.control.lqgmp3d_goal`): a Gaussian in
an ellipsoid against closed forms (χ², non-central χ², the 1-D and 2-D limits), against
Monte Carlo of 10⁶ draws within a binomial interval (anisotropic, off-centre,
near-degenerate), the fast product rule against the adaptive quadrature, and its use in
:func:`riskplan.control.lqgmp3d.lqgmp_3d`."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ndtr
from scipy.stats import chi2, ncx2

import riskplan.control.lqgmp3d_goal as goal_mod
from riskplan.control.lqgmp3d import GOAL_TESTS, lqgmp_3d
from riskplan.control.lqgmp3d_goal import gaussian_in_ellipsoid
from riskplan.errors import InvalidInputError
from riskplan.geometry3d import ConvexBody
from tests.control.test_lqgmp3d import _MovingGoal, _one_step

#: standard errors a Monte Carlo estimate may stray (a statistical threshold: 4.5 gives a
#: false alarm about once in 150,000 comparisons)
Z_BINOMIAL = 4.5


def _rotation(gen):
    q, r = np.linalg.qr(gen.standard_normal((3, 3)))
    return q * np.sign(np.diag(r))


def _ball(r=1.0, centre=(0.0, 0.0, 0.0)):
    return ConvexBody("ellipsoid", np.asarray(centre, dtype=float), r * np.eye(3))


@pytest.mark.parametrize("s", [0.05, 0.3, 0.6, 1.0, 2.0])
def test_centred_isotropic_is_chi_square(tol, s):
    """x ~ N(c, s² I) in the ball of radius r about c: F_χ²₃(r²/s²)."""
    r, c = 0.7, np.array([1.0, -2.0, 0.5])
    p, err = gaussian_in_ellipsoid(_ball(r, c), c, s * s * np.eye(3))
    np.testing.assert_allclose(p, chi2.cdf(r * r / (s * s), 3), **tol["gaussian_in_ellipsoid"])
    assert 0.0 <= err <= tol["gaussian_in_ellipsoid"]["atol"]


@pytest.mark.parametrize("s, off", [(0.2, 0.5), (0.3, 0.9), (0.5, 1.3), (1.0, 0.4), (0.1, 1.05)])
def test_off_centre_isotropic_is_noncentral_chi_square(tol, s, off):
    """x ~ N(m, s² I), |m − c| = off·r: the non-central χ²₃ with λ = |m − c|²/s² at r²/s²."""
    gen = np.random.default_rng(3)
    r, c = 0.5, gen.normal(size=3)
    u = gen.normal(size=3)
    m = c + off * r * u / np.linalg.norm(u)
    p, _ = gaussian_in_ellipsoid(_ball(r, c), m, s * s * np.eye(3))
    want = ncx2.cdf(r * r / (s * s), 3, (off * r / s) ** 2)
    np.testing.assert_allclose(p, want, **tol["gaussian_in_ellipsoid"])


def test_covariance_shaped_like_the_ellipsoid_is_noncentral_chi_square(tol):
    """S = s² A Aᵀ for the ellipsoid {c + A u}: in the body's frame the spread is s² I."""
    gen = np.random.default_rng(4)
    A = _rotation(gen) @ np.diag([0.2, 0.5, 1.1]) @ _rotation(gen)
    body = ConvexBody("ellipsoid", gen.normal(size=3), A)
    for s, a in ((0.4, [0.3, -0.2, 0.5]), (0.25, [0.0, 0.0, 0.0]), (0.8, [1.2, 0.1, 0.0])):
        a = np.asarray(a)
        p, _ = gaussian_in_ellipsoid(body, body.centre + A @ a, s * s * A @ A.T)
        want = ncx2.cdf(1.0 / (s * s), 3, float(a @ a) / (s * s))
        np.testing.assert_allclose(p, want, **tol["gaussian_in_ellipsoid"])


def test_rank_one_is_the_normal_mass_of_the_chord(tol):
    """S = s² v vᵀ: the line m + t v meets the ellipsoid in [t₁, t₂] (a quadratic in t), so
    P = Φ(t₂/s) − Φ(t₁/s); the eigenvalues the round-off leaves in S do not matter."""
    gen = np.random.default_rng(5)
    A = _rotation(gen) @ np.diag([0.3, 0.6, 0.9])
    body = ConvexBody("ellipsoid", gen.normal(size=3), A)
    Ai = np.linalg.inv(A)
    for _ in range(6):
        v = gen.normal(size=3)
        m = body.centre + A @ (gen.uniform(-0.8, 0.8, 3) / math.sqrt(3))
        s = gen.uniform(0.1, 1.5)
        a, w = Ai @ (m - body.centre), Ai @ v  # |a + t w|² ≤ 1
        qa, qb, qc = w @ w, 2 * a @ w, a @ a - 1.0
        root = math.sqrt(qb * qb - 4 * qa * qc)
        t1, t2 = (-qb - root) / (2 * qa), (-qb + root) / (2 * qa)
        want = float(ndtr(t2 / s) - ndtr(t1 / s))
        R = _rotation(gen)  # S through a rotation and back: round-off in the null space
        S = R.T @ (R @ (s * s * np.outer(v, v)) @ R.T) @ R
        p, _ = gaussian_in_ellipsoid(body, m, S)
        np.testing.assert_allclose(p, want, **tol["gaussian_in_ellipsoid"])


def test_rank_two_through_the_centre_is_chi_square_two(tol):
    """S = s² (I − n nᵀ), the mean at the ball's centre: a disc of radius r, F_χ²₂(r²/s²)."""
    gen = np.random.default_rng(6)
    n = gen.normal(size=3)
    n /= np.linalg.norm(n)
    r, c = 0.4, gen.normal(size=3)
    for s in (0.1, 0.3, 0.9):
        p, _ = gaussian_in_ellipsoid(_ball(r, c), c, s * s * (np.eye(3) - np.outer(n, n)))
        np.testing.assert_allclose(p, chi2.cdf(r * r / (s * s), 2), **tol["gaussian_in_ellipsoid"])


def _cases():
    """(body, m, S): anisotropic spread and body, off-centre, near-degenerate (smallest
    variance 1e-9 of the largest), near the edge, a narrow spread inside, a wide one."""
    gen = np.random.default_rng(7)
    out = []
    for scale, off, squash in (
        (0.3, 0.4, 1.0),
        (0.5, 1.0, 1.0),
        (0.2, 0.9, 1e-9),
        (0.8, 1.4, 1e-4),
        (0.05, 0.95, 1.0),
        (2.0, 0.0, 0.1),
    ):
        A = _rotation(gen) @ np.diag(gen.uniform(0.3, 1.2, 3))
        body = ConvexBody("ellipsoid", gen.normal(size=3), A)
        u = gen.normal(size=3)
        m = body.centre + off * A @ (u / np.linalg.norm(u))
        L = _rotation(gen) @ np.diag([1.0, 0.6, math.sqrt(squash)]) * scale
        out.append((body, m, L @ L.T))
    return out


@pytest.mark.parametrize("case", range(6))
def test_agrees_with_a_million_draws(case):
    """10⁶ draws of N(m, S) tested with ``ConvexBody.contains``: within 4.5 binomial
    standard errors of the exact value."""
    body, m, S = _cases()[case]
    p, _ = gaussian_in_ellipsoid(body, m, S)
    n = 1_000_000
    w, V = np.linalg.eigh(S)
    x = (
        m
        + (np.random.default_rng(100 + case).standard_normal((n, 3)) * np.sqrt(np.clip(w, 0, None)))
        @ V.T
    )
    q = float(np.mean(body.contains(x)))
    assert abs(p - q) <= Z_BINOMIAL * math.sqrt(max(p * (1 - p), 1.0 / n) / n)


@pytest.mark.parametrize("case", range(6))
def test_product_rule_agrees_with_adaptive_quadrature(tol, case):
    """The product rule in the angles (the default path) and the nested adaptive quadrature
    in ``z`` (its fallback) agree on the same eigen-coordinates."""
    body, m, S = _cases()[case]
    b, s = goal_mod._coordinates(body, m, S)
    fine = goal_mod._tensor(b, s, 2 * goal_mod._N)
    adaptive, err = goal_mod._adaptive(b, s, 1e-10)
    np.testing.assert_allclose(fine, adaptive, **tol["gaussian_in_ellipsoid"])
    assert err <= tol["gaussian_in_ellipsoid"]["atol"]


def test_settled_cases_and_point_mass(tol):
    """Far outside / deep inside: 0 / 1 with the χ² bound as the error; S = 0: the
    indicator of the mean."""
    ball = _ball(0.1)
    far, e_far = gaussian_in_ellipsoid(ball, np.array([1.0, 0, 0]), 1e-4 * np.eye(3))
    deep, e_deep = gaussian_in_ellipsoid(ball, np.zeros(3), 1e-5 * np.eye(3))
    assert far == 0.0 and deep == 1.0
    np.testing.assert_allclose(
        [e_far, e_deep], chi2.sf([0.9**2 / 1e-4, 0.1**2 / 1e-5], 3), **tol["float64_exact_rel"]
    )
    assert gaussian_in_ellipsoid(ball, np.array([0.05, 0, 0]), np.zeros((3, 3))) == (1.0, 0.0)
    assert gaussian_in_ellipsoid(ball, np.array([0.15, 0, 0]), np.zeros((3, 3))) == (0.0, 0.0)


def test_bad_input():
    box = ConvexBody("box", np.zeros(3), np.eye(3))
    with pytest.raises(InvalidInputError, match="ellipsoid"):
        gaussian_in_ellipsoid(box, np.zeros(3), np.eye(3))
    with pytest.raises(InvalidInputError, match="shapes"):
        gaussian_in_ellipsoid(_ball(), np.zeros(2), np.eye(3))
    with pytest.raises(InvalidInputError, match="finite"):
        gaussian_in_ellipsoid(_ball(), np.array([0, 0, np.nan]), np.eye(3))
    with pytest.raises(InvalidInputError, match="symmetric"):
        gaussian_in_ellipsoid(_ball(), np.zeros(3), np.triu(np.ones((3, 3))))
    with pytest.raises(InvalidInputError, match="semi-definite"):
        gaussian_in_ellipsoid(_ball(), np.zeros(3), -np.eye(3))
    for bad in (0.0, -1.0, float("nan"), "1e-9"):
        with pytest.raises(InvalidInputError, match="tol"):
            gaussian_in_ellipsoid(_ball(), np.zeros(3), np.eye(3), tol=bad)


def test_lqgmp_3d_goal_test_is_exact_by_default(tol):
    """One Gaussian step N(0, s² I) and a ball of radius r: the default goal test gives
    F_χ²₃(r²/s²) to the quadrature's bound (no draws: ``n_goal_samples`` 0, ``goal_test``
    "exact", the standard error field the bound), the same for every method but sampling;
    ``goal="draws"`` draws as before; a box target falls back to draws."""
    s2, r = 0.01, 0.15
    plan, ctrl = _one_step(s2 * np.eye(3))
    sim = _MovingGoal(r, 0.0)
    want = float(chi2.cdf(r * r / s2, 3))
    for method in ("truncation", "per-step", "sigma"):
        got = lqgmp_3d(sim, plan, ctrl, method=method, seed=0)
        np.testing.assert_allclose(got.p_goal, want, **tol["gaussian_in_ellipsoid"])
        assert got.goal_test == "exact" and got.n_goal_samples == 0
        assert 0.0 <= got.p_success_se <= tol["gaussian_in_ellipsoid"]["atol"]
    drawn = lqgmp_3d(sim, plan, ctrl, method="truncation", goal="draws", n_goal_samples=4000)
    assert drawn.goal_test == "draws" and drawn.n_goal_samples == 4000
    assert abs(drawn.p_goal - want) <= Z_BINOMIAL * math.sqrt(want * (1 - want) / 4000)
    sampled = lqgmp_3d(sim, plan, ctrl, method="sampling", n_goal_samples=500, seed=0)
    assert sampled.goal_test == "draws" and sampled.n_goal_samples == 500
    with pytest.raises(InvalidInputError, match="goal"):
        lqgmp_3d(sim, plan, ctrl, goal="quadrature")
    assert GOAL_TESTS == ("exact", "draws")

    class _BoxGoal(_MovingGoal):
        def goal(self, state):
            return ConvexBody("box", np.zeros(3), self.r * np.eye(3))

    boxed = lqgmp_3d(_BoxGoal(r, 0.0), plan, ctrl, method="truncation", n_goal_samples=300)
    assert boxed.goal_test == "draws" and boxed.n_goal_samples == 300


def test_goal_test_takes_an_indefinite_covariance_as_its_nearest_semidefinite_one(tol):
    """A final covariance indefinite beyond round-off (a residual of the statistical
    linearisation) is clipped to its nearest positive semi-definite matrix, as the draws'
    eigen-factor does, instead of raising."""
    from riskplan.control.lqgmp3d import _goal_test

    n = np.array([1.0, 2.0, 2.0]) / 3.0
    S = 0.04 * (np.eye(3) - np.outer(n, n)) - 1e-6 * np.outer(n, n)  # eigenvalue −1e-6
    ball = _ball(0.3)
    p, n_draws, err, used = _goal_test(ball, np.zeros(3), S, "exact", None)
    clipped, _ = gaussian_in_ellipsoid(ball, np.zeros(3), 0.04 * (np.eye(3) - np.outer(n, n)))
    np.testing.assert_allclose(p, clipped, **tol["float64_ref"])
    np.testing.assert_allclose(p, chi2.cdf(0.3**2 / 0.04, 2), **tol["gaussian_in_ellipsoid"])
    assert (n_draws, used) == (0, "exact") and err <= tol["gaussian_in_ellipsoid"]["atol"]
