"""The 3-D needle's second-order step and statistically linearised tip: the control
derivatives against the closed-form step, the second-order mean of one step against Monte
Carlo, the tip's statistical linearisation against Monte Carlo of the tissue response and,
for a vanishing spread, against its central-difference Jacobian."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.control import NominalPlan
from riskplan.control.lqgmp3d_moments import _second_order_mean
from riskplan.errors import InvalidInputError
from riskplan.scenarios.bevel import pose_step_jacobian, se3_exp_batch
from riskplan.scenarios.needle3d import Needle3DScenario, Needle3DState

#: z-score of the Monte Carlo checks (two-sided, about 6e-5 per comparison)
Z = 4.0


@pytest.fixture(scope="module")
def sim():
    return Needle3DScenario()


@pytest.fixture(scope="module")
def pushed(sim):
    """A state 5 steps into the block (the tissue pushed at the tip; there the gradient at
    the point gives a spread 20 % off the tissue's over a few hundredths)."""
    y = sim.initial_state()
    for _ in range(5):
        y = sim.step(y, [0.3, 1.5])
    return y


def _steps(sim, m, U):
    """``K(u) m`` for each control row of ``U (n, 2)`` and each pose row of ``m (n, 12)``,
    batched through the screw exponential (the independent closed form)."""
    cfg = sim.config
    n = U.shape[0]
    xi = np.zeros((n, 6))
    xi[:, 2] = cfg.tau * U[:, 0]
    xi[:, 3] = cfg.tau * cfg.curvature * U[:, 0]
    xi[:, 5] = cfg.tau * U[:, 1]
    E, d = se3_exp_batch(xi)
    R = m[:, 3:].reshape(n, 3, 3).transpose(0, 2, 1)  # columns e1, e2, e3
    p = m[:, :3] + np.einsum("nij,nj->ni", R, d)
    R1 = R @ E
    return np.concatenate([p, R1.transpose(0, 2, 1).reshape(n, 9)], axis=1)


def test_step_derivatives_give_the_taylor_expansion(sim, pushed, tol):
    """K(u* + δ) m* = K m* + Σ K_k m* δ_k + ½ Σ K_kl m* δ_k δ_l + O(|δ|³) against the
    closed-form step, for steps of 1e-3 in the control (third-order rest below 1e-8)."""
    u = np.array([0.3, 1.5])
    m, K, dK, d2K = sim.material_step_derivatives(pushed, u)
    cfg = sim.config
    np.testing.assert_allclose(
        K,
        pose_step_jacobian(u[0], u[1], tau=cfg.tau, kappa=cfg.curvature),
        **tol["float64_exact"],
    )
    gen = np.random.default_rng(0)
    D = gen.standard_normal((5, 2)) * np.array([1e-3, 1e-3])
    exact = _steps(sim, np.tile(m, (5, 1)), u + D)
    for k, d in enumerate(D):
        taylor = K @ m + np.einsum("kij,k,j->i", dK, d, m)
        taylor += 0.5 * np.einsum("klij,k,l,j->i", d2K, d, d, m)
        np.testing.assert_allclose(taylor, exact[k], **tol["fd_jacobian"])


def test_second_order_mean_of_one_step_matches_monte_carlo(sim, pushed):
    """One step from a joint Gaussian of the pose deviation and the control deviation (the
    actuation noise plus a feedback correlated with the pose): the mean deviation to second
    order, K μ_m + B_m μ_u + Σ K_k (Cov(δm, δu_k) + μ_u,k μ_m) + ½ Σ K_kl m* E[δu_k δu_l],
    against 200,000 draws of the closed-form step; the first-order mean misses it."""
    u = np.array([0.3, 1.5])
    m, K, dK, d2K = sim.material_step_derivatives(pushed, u)
    gen = np.random.default_rng(1)
    Lm = gen.standard_normal((14, 14)) * 0.02
    Lm[12, 12], Lm[13, 13] = 0.05, 1.0  # v and ω spread as the actuation noise
    Lm[12:, :12] *= 5.0  # the feedback's correlation with the pose
    C = Lm @ Lm.T
    mean = np.concatenate([gen.standard_normal(12) * 0.005, [0.01, 0.2]])
    n = 200_000
    Zs = mean + gen.standard_normal((n, 14)) @ Lm.T
    out = _steps(sim, m + Zs[:, :12], u + Zs[:, 12:]) - K @ m
    Bm = np.einsum("kij,j->ik", dK, m)
    first = K @ mean[:12] + Bm @ mean[12:]
    second = first + _second_order_mean(dK, d2K, m, mean[:12], mean[12:], C[12:, 12:], C[:12, 12:])
    se = out.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(out.mean(axis=0) - second) <= Z * se)
    assert np.any(np.abs(out.mean(axis=0) - first) > 3 * Z * se)


def test_tip_moments_for_a_vanishing_spread_is_the_jacobian(sim, pushed, tol):
    """Σ → 0: Φ is the tip's Jacobian in (X, e₃) (central differences of the tissue
    response; both exact on the element's quadratic up to round-off), Δ and R vanish."""
    Jx = sim._material_differences(pushed, sim.nominal_params)[1]
    S = np.eye(12) * 1e-14
    Phi, offset, R = sim.tip_moments(pushed, np.zeros(12), S)
    np.testing.assert_allclose(Phi[:, [0, 1, 2, 9, 10, 11]], Jx, **tol["fd_quadratic"])
    assert not Phi[:, 3:9].any()
    assert np.abs(offset).max() <= tol["fd_quadratic"]["rtol"] * np.abs(Jx).max()
    assert np.abs(R).max() <= tol["fd_quadratic"]["rtol"] * np.abs(Jx).max() ** 2


def test_tip_moments_match_monte_carlo_of_the_tissue(sim, pushed):
    """A spread of a few hundredths (several tetrahedra): the statistical linearisation's
    mean and standard deviations of the world tip against 4000 draws of the tissue response,
    inside the Monte Carlo's intervals; the gradient at the point does not reproduce the
    spread."""
    gen = np.random.default_rng(2)
    F = np.zeros((12, 12))
    F[:3, :3] = np.diag([0.02, 0.015, 0.015])
    F[9:, 9:] = np.diag([0.05, 0.05, 0.02])
    S = F @ F.T
    mu = np.concatenate([[0.003, -0.002, 0.0], np.zeros(9)])
    Phi, offset, R = sim.tip_moments(pushed, mu, S)
    params = sim.nominal_params
    n = 4000
    m0 = np.array(pushed.material)
    X = np.array(
        [sim._tissue_response(m0 + mu + F @ z, params)[1][:3] for z in gen.standard_normal((n, 12))]
    )
    mc_mean = X.mean(axis=0) - pushed.pose[:3]
    mc_sd = X.std(axis=0, ddof=1)
    sd = np.sqrt(np.diag(Phi @ S @ Phi.T + R))
    assert np.all(np.abs(offset + Phi @ mu - mc_mean) <= Z * mc_sd / np.sqrt(n))
    assert np.all(np.abs(sd - mc_sd) <= Z * mc_sd / np.sqrt(2 * n))
    Jx = sim._material_differences(pushed, params)[1]
    J = np.zeros((3, 12))
    J[:, [0, 1, 2, 9, 10, 11]] = Jx
    sd_point = np.sqrt(np.diag(J @ S @ J.T))
    assert np.any(np.abs(sd_point - mc_sd) > Z * mc_sd / np.sqrt(2 * n))


def test_tip_moments_kinds_and_frames(sim, pushed, tol):
    """The material frame's position is X itself (identity map); the relative kind moves
    with the target (its slope differs from the tip's); bad kinds are rejected."""
    S = np.eye(12) * 1e-6
    mat = sim.with_frame("material")
    Phi, offset, R = mat.tip_moments(pushed, np.zeros(12), S, kind="position")
    np.testing.assert_array_equal(Phi[:, :3], np.eye(3))
    assert not offset.any() and not R.any()
    assert sim.position_is_measured and not mat.position_is_measured
    tip = sim.tip_moments(pushed, np.zeros(12), S, kind="measured")[0]
    rel = sim.tip_moments(pushed, np.zeros(12), S, kind="relative")[0]
    np.testing.assert_allclose(
        rel[:, [0, 1, 2, 9, 10, 11]],
        tip[:, [0, 1, 2, 9, 10, 11]] - sim._material_differences(pushed, sim.nominal_params)[0],
        **tol["fd_quadratic"],
    )
    with pytest.raises(InvalidInputError, match="kind"):
        sim.tip_moments(pushed, np.zeros(12), S, kind="tip")
    with pytest.raises(InvalidInputError, match="cov"):
        sim.tip_moments(pushed, np.zeros(12), np.eye(3))


def _perturbed_state(sim, y, dm):
    """``y`` with its material pose moved by ``dm (12,)`` and the push recomputed there."""
    mat = np.array(y.material) + dm
    disp, pose = sim._tissue_response(mat, sim.nominal_params)
    return Needle3DState(
        t=y.t,
        displacement=disp,
        n_elements=y.n_elements,
        pose=pose,
        material=mat,
        applied=y.applied,
    )


@pytest.mark.parametrize("frame", ["world", "material"])
def test_linear_model_against_central_differences_of_the_simulator(sim, tol, frame):
    """``A_t``, ``B_t`` of the structured model against central differences of the full
    step (kinematics and tissue) at a plan's states: perturbed controls for ``B``, perturbed
    material poses (the reduced state moved by ``P_t δm``) for ``A``; ``M = B Σ_w Bᵀ``."""
    s = sim.with_frame(frame)
    controls = np.tile([[0.3, 1.5]], (7, 1))
    plan = NominalPlan.from_rollout(s, s.initial_state(), controls).reframed(s)
    W = np.diag([0.05, 1.0]) ** 2
    A, B, M, H, N = s.linear_model(plan, W)
    np.testing.assert_array_equal(N[0], s.sensing_cov)
    h = 1e-6
    for t in (3, 5):
        y, u = plan.states[t], plan.controls[t]
        for k in range(2):
            e = np.zeros(2)
            e[k] = h
            fd = (s.reduced(s.step(y, u + e)) - s.reduced(s.step(y, u - e))) / (2 * h)
            np.testing.assert_allclose(B[t][:, k], fd, **tol["fd_jacobian"])
        for i in (0, 2, 4, 10):
            dm = np.zeros(12)
            dm[i] = h
            yp, ym = _perturbed_state(s, y, dm), _perturbed_state(s, y, -dm)
            dx = (s.reduced(yp) - s.reduced(ym)) / 2
            fd = (s.reduced(s.step(yp, u)) - s.reduced(s.step(ym, u))) / 2
            np.testing.assert_allclose(A[t] @ dx / h, fd / h, **tol["fd_jacobian"])
    np.testing.assert_allclose(M, np.einsum("tik,kl,tjl->tij", B, W, B), **tol["float64_exact"])
    np.testing.assert_allclose(
        H[-1], s.observation_jacobian(plan.states[-1]), **tol["float64_exact"]
    )
