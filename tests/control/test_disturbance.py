"""The persistent-disturbance state (beyond the paper): the least-squares fit of d, the
augmented LQR against a direct Riccati recursion, the constant-offset closed forms of the
plain and the augmented loop, LQG-MP with d against Monte Carlo of the same linear model,
and the paper's formulation untouched without the option."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from riskplan.control import (
    Disturbance,
    Linearization,
    NominalPlan,
    augmented_model,
    execute,
    linearize,
    lqg_controller,
    lqgmp,
    lqr_gains,
    monte_carlo_success,
)
from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import SimParams
from riskplan.scenarios.uncertainty import ActuationNoise, ParamDistribution
from tests.conftest import TOL

from .toy import FORCE, LinearToy, square, toy_system


class QuietSensor(LinearToy):
    """The toy whose measurements carry no noise (its filter still assumes ``N``): an
    execution is then a deterministic function of the drawn parameters."""

    def observe(self, x, noise=None, rng=None):
        return self.observation_matrix @ np.asarray(x)


@dataclass(frozen=True)
class GaussianOffset(ParamDistribution):
    """``force_scale = 1 + sd ξ`` (ξ standard normal; below 0 with probability 3e-5 at
    sd = 0.25, then clipped) and, optionally, per-step actuation noise ``cov``. On the toy
    with ``c = B d0`` the persistent offset is ``d = d0 (f − 1) ~ N(0, sd² d0 d0ᵀ)``."""

    name: str = "gaussian-offset"
    sd: float = 0.25
    cov: tuple | None = field(default=None)

    def _draw(self, gen):
        f = max(0.0, 1.0 + self.sd * float(gen.standard_normal()))
        if self.cov is None:
            return self.base.replace(force_scale=f)
        return self.base.replace(
            force_scale=f, actuation_cov=self.cov, actuation_seed=int(gen.integers(0, 2**63 - 1))
        )


def _exact(sim, T, Sigma_d, W=None):
    """The toy's exact linear model with the disturbance model ``Σ_d``, residual ``B W Bᵀ``
    (per-step actuation noise) and the paper's ``M = B (W + Σ_d) Bᵀ`` (all of it as noise)."""
    p, q = sim.B_true.shape
    W = np.zeros((q, q)) if W is None else W
    m = sim.observation_matrix.shape[0]
    Mr = sim.B_true @ W @ sim.B_true.T
    return Linearization(
        A=np.broadcast_to(sim.A_true, (T, p, p)),
        B=np.broadcast_to(sim.B_true, (T, p, q)),
        M=np.broadcast_to(sim.B_true @ (W + Sigma_d) @ sim.B_true.T, (T, p, p)),
        H=np.broadcast_to(sim.observation_matrix, (T, m, p)),
        N=np.broadcast_to(sim.sensing_cov, (T, m, m)),
        rank=np.full(T, p),
        disturbance=Disturbance(
            cov=Sigma_d, M=np.broadcast_to(Mr, (T, p, p)), fits=np.zeros((0, q)), weights=np.ones(p)
        ),
    )


# ---- the least-squares fit (linearize) ---------------------------------------------------


def test_fit_recovers_a_known_constant_disturbance(rng, tol):
    # x_{t+1} = A x + B u + c (f − 1) with c = B d0: draw i is exactly the constant input
    # disturbance d_i = d0 (f_i − 1); p = 4 > q = 2, so the fit has to find it through B.
    A, _, _ = toy_system(rng, p=4, q=2)
    B = rng.standard_normal((4, 2))
    d0 = np.array([0.3, -0.2])
    sim = LinearToy(A, B, c=B @ d0)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), rng.uniform(-1, 1, (6, 2)))
    f = np.array([0.2, 0.7, 1.0, 1.4, 1.9])
    draws = [SimParams(force_scale=v) for v in f]
    with pytest.warns(RuntimeWarning):  # q < p: X_t has rank 2, A keeps its prior (B is exact)
        lin = linearize(sim, plan, draws, seed=0, disturbance=True)
    dist = lin.disturbance
    expected = np.outer(f - 1.0, d0)
    np.testing.assert_allclose(dist.fits, expected, **tol["float64_ref"])
    np.testing.assert_allclose(dist.cov, expected.T @ expected / len(f), **tol["float64_ref"])
    # nothing is left for the residual noise, where the paper's M holds all of it
    np.testing.assert_allclose(dist.M, 0.0, **tol["float64_ref"])
    np.testing.assert_allclose(lin.M[0], B @ dist.cov @ B.T, **tol["float64_ref"])


def test_an_offset_outside_the_range_of_B_stays_in_the_residual(rng, tol):
    # c ⊥ range(B): no constant input disturbance explains it; the fit is 0, M^r = M
    A, _, _ = toy_system(rng, p=3, q=2)
    B = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    sim = LinearToy(A, B, c=np.array([0.0, 0.0, 0.5]))
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), rng.uniform(-1, 1, (4, 2)))
    with pytest.warns(RuntimeWarning):  # x3 is not excited by the controls
        lin = linearize(sim, plan, FORCE, n_samples=8, seed=0, disturbance=True)
    np.testing.assert_allclose(lin.disturbance.fits, 0.0, **tol["float64_ref"])
    np.testing.assert_allclose(lin.disturbance.M, lin.M, **tol["float64_ref"])


def test_actuation_noise_stays_per_step(rng, tol):
    A, B, _ = toy_system(rng, p=3, q=3)
    d0 = np.array([0.2, 0.0, -0.1])
    sim = LinearToy(A, B, c=B @ d0)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), rng.uniform(-1, 1, (5, 3)))
    cov = tuple(map(tuple, 0.01 * np.eye(3)))
    # actuation noise alone: nothing persistent (no extra runs), M^r is the paper's M
    act = linearize(sim, plan, ActuationNoise(cov=cov), n_samples=12, seed=1, disturbance=True)
    np.testing.assert_array_equal(act.disturbance.fits, 0.0)
    np.testing.assert_array_equal(act.disturbance.cov, 0.0)
    np.testing.assert_allclose(act.disturbance.M, act.M, **tol["float64_exact"])
    # force and actuation noise in the same draws: d is fitted from the runs without the
    # actuation noise, so it is exactly the force's offset; the noise stays in M^r
    both = GaussianOffset(cov=cov).sample_many(12, seed=2)
    lin = linearize(sim, plan, both, seed=1, disturbance=True)
    f = np.array([s.force_scale for s in both])
    np.testing.assert_allclose(lin.disturbance.fits, np.outer(f - 1.0, d0), **tol["float64_ref"])
    assert np.trace(lin.disturbance.M[2]) > 0.25 * 0.01 * np.trace(B @ B.T)


def test_the_option_leaves_the_paper_model_bit_identical(rng):
    A, B, c = toy_system(rng, p=3, q=3)
    sim = LinearToy(A, B, c=c)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), rng.uniform(-1, 1, (5, 3)))
    sim._goal = square(*plan.reduced[-1, :2], 0.5)
    plain = linearize(sim, plan, FORCE, n_samples=8, seed=3)
    withd = linearize(sim, plan, FORCE, n_samples=8, seed=3, disturbance=True)
    assert plain.disturbance is None and withd.disturbance is not None
    for name in ("A", "B", "M", "H", "N", "rank", "drift"):
        np.testing.assert_array_equal(getattr(plain, name), getattr(withd, name))
    a, b = lqg_controller(plain), lqg_controller(withd)
    assert not b.disturbance
    for name in ("L", "K", "P", "P0"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    ra = lqgmp(sim, plan, a, method="sampling", n_goal_samples=200, seed=0)
    rb = lqgmp(sim, plan, b, method="sampling", n_goal_samples=200, seed=0)
    np.testing.assert_array_equal(ra.cov, rb.cov)
    assert ra.p_success == rb.p_success
    ea = execute(sim, plan, a, SimParams(force_scale=1.5), seed=0)
    eb = execute(sim, plan, b, SimParams(force_scale=1.5), seed=0)
    np.testing.assert_array_equal(ea.x, eb.x)
    np.testing.assert_array_equal(ea.estimates, eb.estimates)
    assert ea.disturbance is None
    with pytest.raises(InvalidInputError, match="disturbance"):
        lqg_controller(plain, disturbance=True)


# ---- LQR and the closed loop ------------------------------------------------------------


def _riccati_cross(A, B, Q, R, Nx, Qf):
    """Finite-horizon LQR with a state-input cross term, cost Σ (zᵀQz + 2 zᵀNx u + uᵀRu) +
    z_Tᵀ Qf z_T, ``u = L z`` (Bertsekas vol. 1, ch. 4, with the cross term completed)."""
    T = A.shape[0]
    S = Qf
    L = [None] * T
    for t in range(T - 1, -1, -1):
        G = B[t].T @ S @ B[t] + R
        Hm = B[t].T @ S @ A[t] + Nx.T
        L[t] = -np.linalg.solve(G, Hm)
        S = Q + A[t].T @ S @ A[t] - Hm.T @ np.linalg.solve(G, Hm)
        S = 0.5 * (S + S.T)
    return np.stack(L)


def test_augmented_gain_is_plain_lqr_plus_feedforward(rng, tol):
    # the cost Σ x̄ᵀQx̄ + (ū + d)ᵀR(ū + d) on the augmented system z = (x̄, d), written as a
    # general LQR with cross term, gives [L_plain, −I]
    T, p, q = 7, 3, 2
    A = np.eye(p) + 0.3 * rng.standard_normal((T, p, p))
    B = rng.standard_normal((T, p, q))
    Q = np.diag(rng.uniform(0.5, 2.0, p))
    R = np.diag(rng.uniform(0.5, 2.0, q))
    Qf = 3.0 * Q
    Lp = lqr_gains(A, B, Q, R, Qf)
    Az = np.zeros((T, p + q, p + q))
    Az[:, :p, :p], Az[:, :p, p:], Az[:, p:, p:] = A, B, np.eye(q)
    Bz = np.concatenate([B, np.zeros((T, q, q))], axis=1)
    Qz = np.block([[Q, np.zeros((p, q))], [np.zeros((q, p)), R]])
    Nz = np.concatenate([np.zeros((p, q)), R])
    Qfz = np.block([[Qf, np.zeros((p, q))], [np.zeros((q, p)), np.zeros((q, q))]])
    Lz = _riccati_cross(Az, Bz, Qz, R, Nz, Qfz)
    np.testing.assert_allclose(Lz[:, :, :p], Lp, **tol["float64_ref"])
    np.testing.assert_allclose(
        Lz[:, :, p:], np.broadcast_to(-np.eye(q), (T, q, q)), **tol["float64_ref"]
    )
    # and lqg_controller builds exactly that gain
    lin = Linearization(
        A=A,
        B=B,
        M=np.zeros((T, p, p)),
        H=np.broadcast_to(np.eye(p), (T, p, p)),
        N=np.broadcast_to(np.eye(p), (T, p, p)),
        rank=np.full(T, p),
        disturbance=Disturbance(
            cov=np.eye(q), M=np.zeros((T, p, p)), fits=np.zeros((0, q)), weights=np.ones(p)
        ),
    )
    ctrl = lqg_controller(lin, Q=Q, R=R, Q_final=Qf, disturbance=True)
    np.testing.assert_allclose(ctrl.L, Lz, **tol["float64_ref"])
    assert ctrl.K.shape == (T, p + q, p) and ctrl.P0.shape == (p + q, p + q)


def _offset_toy(a=0.9, b=0.5, delta=0.4, T=80):
    """Two decoupled copies of x' = a x + b (u + d) with d = (δ (f − 1), 0)."""
    d0 = np.array([delta, 0.0])
    sim = QuietSensor(a * np.eye(2), b * np.eye(2), c=b * d0, sensing_std=0.01)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), np.zeros((T, 2)))
    sim._goal = square(0.0, 0.0, 100.0)
    Sigma_d = np.outer(d0, d0) / 3.0  # d = d0 (f − 1), f ~ U[0, 2]
    return sim, plan, _exact(sim, T, Sigma_d), d0


def test_constant_offset_plain_loop_cannot_remove_it(tol):
    # Plain LQG (the paper's), constant d, noiseless measurements: with stationary gains
    # L, K the loop is
    #     x_{t+1} = a x_t + b (L x̂_t + d),   x̂_{t+1} = (1 − K)(a + b L) x̂_t + K x_{t+1},
    # whose fixed point is x̂ = κ x, κ = K / (1 − (1 − K)(a + b L)), and
    #     x_∞ = b d / (1 − a − b L κ)  ≠ 0  for every finite L, K.
    a, b, T = 0.9, 0.5, 80
    sim, plan, lin, d0 = _offset_toy(a, b, T=T)
    f = 1.8
    d = d0[0] * (f - 1.0)
    plain = lqg_controller(lin)
    t = T // 2  # mid-horizon: the gains are stationary here
    L, K = plain.L[t][0, 0], plain.K[t][0, 0]
    for G in (plain.L, plain.K):
        np.testing.assert_allclose(
            G[t - 10 : t + 1], np.broadcast_to(G[t], (11, *G.shape[1:])), **tol["float64_ref"]
        )
    kappa = K / (1.0 - (1.0 - K) * (a + b * L))
    x_inf = b * d / (1.0 - a - b * L * kappa)
    ex = execute(sim, plan, plain, SimParams(force_scale=f))
    np.testing.assert_allclose(ex.x[t, 0], x_inf, **tol["steady_state"])
    # the offset stays to the end of the plan (feedback shrinks it from the open loop's
    # b d / (1 − a) but cannot remove it)
    assert abs(ex.x[-1, 0]) > 0.5 * abs(x_inf) and abs(x_inf) < abs(b * d / (1.0 - a))
    np.testing.assert_allclose(ex.x[:, 1], 0.0, **tol["float64_abs"])


def test_constant_offset_augmented_loop_removes_it(tol):
    # Augmented loop: with noiseless measurements and an exact model the filter's error
    # e_t = (ξ − ξ̂)_t follows e_{t+1} = (I − K_t H̄) Ā_t e_t from e_0 = (0, d), and the state
    #     x_{t+1} = (A + B L_t) x_t + B (e_d,t − L_t e_x,t)
    # (u = L x̂ − d̂ + d). Its fixed point is x = 0: the offset goes, at the rate the filter
    # learns d (∝ 1/t without process noise on d).
    a, b, T = 0.9, 0.5, 80
    sim, plan, lin, d0 = _offset_toy(a, b, T=T)
    f = 1.8
    d = d0 * (f - 1.0)
    ctrl = lqg_controller(lin, disturbance=True)
    ex = execute(sim, plan, ctrl, SimParams(force_scale=f))
    Ab, _, Hb, _, _ = augmented_model(lin)
    p = 2
    e = np.concatenate([np.zeros(p), d])
    x = np.zeros(p)
    xs = [x]
    for t in range(T):
        Lx = ctrl.L[t][:, :p]
        x = (lin.A[t] + lin.B[t] @ Lx) @ x + lin.B[t] @ (e[p:] - Lx @ e[:p])
        e = (np.eye(p + 2) - ctrl.K[t] @ Hb[t]) @ Ab[t] @ e
        xs.append(x)
    np.testing.assert_allclose(ex.x, np.stack(xs), **tol["float64_ref"])
    np.testing.assert_allclose(ex.disturbance[-1], d - e[p:], **tol["float64_ref"])
    plain = execute(sim, plan, lqg_controller(lin), SimParams(force_scale=f))
    assert abs(ex.x[-1, 0]) < 0.01 * abs(plain.x[-1, 0])
    assert abs(ex.disturbance[-1, 0] - d[0]) < 0.01 * abs(d[0])


# ---- LQG-MP with d ----------------------------------------------------------------------

SIGMA_W = 0.05


def _wall(x_edge, y_lo, y_hi):
    return np.array([[x_edge, y_lo], [x_edge + 100, y_lo], [x_edge + 100, y_hi], [x_edge, y_hi]])


def _wall_toy(T=8):
    # A = I, B = I: a persistent sideways offset d = d0 (f − 1) pushes the path towards a
    # wall; per-step actuation noise and sensing noise on top.
    d0 = np.array([0.3, 0.0, 0.0])  # d ~ N(0, 0.075²) per step in x, actuation sd 0.05
    cov = tuple(map(tuple, SIGMA_W**2 * np.eye(3)))
    dist = GaussianOffset(sd=0.25, cov=cov)
    sim = LinearToy(np.eye(3), np.eye(3), c=d0, sensing_std=0.05, distribution=dist)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), np.tile([0.0, 0.1, 0.0], (T, 1)))
    sim._obstacles = [_wall(0.15, 0.15, 0.85)]
    sim._goal = square(0.0, 0.8, 0.3)
    Sigma_d = dist.sd**2 * np.outer(d0, d0)
    return sim, plan, _exact(sim, T, Sigma_d, W=SIGMA_W**2 * np.eye(3))


def test_lqgmp_with_d_covariance_matches_monte_carlo(rng):
    # second moments propagate exactly through a linear system whatever the distribution:
    # whitened E[ξ_T ξ_Tᵀ] of (x̄_T, d, x̂_T, d̂_T) from executions ≈ I
    T, n = 8, 600
    sim, plan, lin = _wall_toy(T)
    sim._obstacles = []
    ctrl = lqg_controller(lin, disturbance=True)
    res = lqgmp(sim, plan, ctrl, n_goal_samples=10)
    assert res.cov.shape == (T + 1, 12, 12)
    d0 = sim.c
    xi = np.empty((n, 12))
    for k in range(n):
        gen = np.random.default_rng(5000 + k)
        params = sim.distribution.sample(gen)
        ex = execute(sim, plan, ctrl, params, seed=gen, keep_states=False)
        xi[k, :3] = ex.x[-1] - plan.reduced[-1]
        xi[k, 3:6] = d0 * (params.force_scale - 1.0)
        xi[k, 6:9] = ex.estimates[-1] - plan.reduced[-1]
        xi[k, 9:] = ex.disturbance[-1]
    S = res.cov[T]
    w, v = np.linalg.eigh(S)
    keep = w > TOL["covariance_support"]["rtol"] * w.max()
    Wh = v[:, keep] / np.sqrt(w[keep])
    E = (xi @ Wh).T @ (xi @ Wh) / n
    sd = np.where(np.eye(keep.sum(), dtype=bool), math.sqrt(2 / n), math.sqrt(1 / n))
    assert np.all(np.abs(E - np.eye(keep.sum())) < 4.5 * sd), np.round(E, 3)
    if (~keep).any():
        assert np.abs(xi @ v[:, ~keep]).max() < TOL["covariance_support"]["atol"]


def test_lqgmp_sampling_with_d_matches_executions():
    # the linear toy with a Gaussian persistent offset and actuation noise *is* the
    # augmented linear-Gaussian model: LQG-MP "sampling" of the disturbance-state controller
    # must agree with its executions within Monte Carlo error
    T = 8
    sim, plan, lin = _wall_toy(T)
    ctrl = lqg_controller(lin, disturbance=True)
    n_mc, n_s = 2000, 40_000
    mc = monte_carlo_success(sim, plan, ctrl, sim.distribution, n=n_mc, seed=7)
    smp = lqgmp(sim, plan, ctrl, method="sampling", n_goal_samples=n_s, seed=0)
    p = mc.probability
    se = math.sqrt(p * (1 - p) * (1 / n_mc + 1 / n_s))
    assert 0.2 < p < 0.9, p  # the wall matters
    assert abs(smp.p_success - p) < 4.5 * se, (smp.p_success, p, se)
    # sigma and truncation run on the augmented model too (lower than sampling, as always)
    for method in ("sigma", "truncation"):
        r = lqgmp(sim, plan, ctrl, method=method, n_goal_samples=n_s, seed=0)
        assert 0.0 <= r.p_success <= smp.p_success + 4.5 * se
    with pytest.raises(InvalidInputError, match="drift"):
        lqgmp(sim, plan, ctrl, drift=True)


def test_plan_selection_passes_the_option(rng):
    from riskplan.tissue_planning.select import select_plan

    sim, plan, _ = _wall_toy(4)
    other = NominalPlan.from_rollout(sim, sim.initial_state(), np.tile([-0.05, 0.1, 0.0], (4, 1)))
    sel = select_plan(
        sim, [plan, other], n_samples=8, n_goal_samples=200, backend="serial", disturbance=True
    )
    assert all(c.disturbance for c in sel.controllers)
    assert sel.result.cov.shape == (5, 12, 12)
    plain = select_plan(sim, [plan, other], n_samples=8, n_goal_samples=200, backend="serial")
    assert not any(c.disturbance for c in plain.controllers)
