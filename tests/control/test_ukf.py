"""UKF: equals the Kalman filter on a linear-Gaussian model; beats the EKF's linearisation
against Monte Carlo on a nonlinear map; selectable in execute."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.control import execute, kalman_gains, linearize, lqg_controller
from riskplan.control.ukf import sigma_points, ukf_step, unscented_transform
from riskplan.errors import InvalidInputError

from .test_lqg import _setup


def test_linear_gaussian_equals_kalman(rng, tol):
    T, p, q, m = 12, 3, 2, 2
    A = np.eye(p) + 0.2 * rng.standard_normal((T, p, p))
    B = rng.standard_normal((T, p, q))
    H = rng.standard_normal((T, m, p))
    M = np.diag(rng.uniform(0.01, 0.1, p))
    N = np.diag(rng.uniform(0.05, 0.2, m))
    P0 = 0.3 * np.eye(p)
    K, P = kalman_gains(A, H, M, N, P0)
    xk = xu = rng.standard_normal(p)
    Pu = P0
    for t in range(T):
        u, z = rng.standard_normal(q), rng.standard_normal(m)
        xp = A[t] @ xk + B[t] @ u
        xk = xp + K[t] @ (z - H[t] @ xp)
        xu, Pu = ukf_step(
            xu, Pu, lambda x, t=t, u=u: A[t] @ x + B[t] @ u, lambda x, t=t: H[t] @ x, M, N, z
        )
        np.testing.assert_allclose(xu, xk, **tol["float64_ref"])
        np.testing.assert_allclose(Pu, P[t], **tol["float64_ref"])


def test_weights_sum_and_moments(rng, tol):
    n = 4
    mean = rng.standard_normal(n)
    L = rng.standard_normal((n, n))
    cov = L @ L.T
    for alpha, kappa in ((1.0, 0.0), (0.5, 1.0), (1e-1, 3.0 - n)):
        chi, wm, wc = sigma_points(mean, cov, alpha=alpha, kappa=kappa)
        np.testing.assert_allclose(wm.sum(), 1.0, **tol["float64_exact"])
        np.testing.assert_allclose(wm @ chi, mean, **tol["float64_exact"])
        d = chi - mean
        np.testing.assert_allclose((wc[1:, None] * d[1:]).T @ d[1:], cov, **tol["float64_exact"])
    with pytest.raises(InvalidInputError, match="alpha"):
        sigma_points(mean, cov, alpha=1.0, kappa=-n)


def test_polar_to_cartesian_beats_ekf_against_monte_carlo(rng):
    """Range/bearing (r, θ) → (r cos θ, r sin θ) with a 0.4 rad bearing spread: the
    linearisation (EKF) misses the mean's pull towards the sensor and the covariance's
    curvature; the unscented transform captures more of both. Reference: 400 000 draws."""
    mean = np.array([1.0, np.pi / 2])
    cov = np.diag([0.02**2, 0.4**2])

    def f(x):
        return np.array([x[0] * np.cos(x[1]), x[0] * np.sin(x[1])])

    draws = rng.multivariate_normal(mean, cov, size=400_000)
    ys = np.stack([draws[:, 0] * np.cos(draws[:, 1]), draws[:, 0] * np.sin(draws[:, 1])], axis=1)
    mc_mean, mc_cov = ys.mean(axis=0), np.cov(ys.T)
    J = np.array(
        [
            [np.cos(mean[1]), -mean[0] * np.sin(mean[1])],
            [np.sin(mean[1]), mean[0] * np.cos(mean[1])],
        ]
    )
    ekf_mean, ekf_cov = f(mean), J @ cov @ J.T
    ukf_mean, ukf_cov, _ = unscented_transform(f, mean, cov)
    # the Monte Carlo standard error of the mean is ~ 0.4 / sqrt(4e5) = 6e-4, far below both gaps
    assert np.linalg.norm(ukf_mean - mc_mean) < 0.5 * np.linalg.norm(ekf_mean - mc_mean)
    assert np.linalg.norm(ukf_cov - mc_cov) < 0.5 * np.linalg.norm(ekf_cov - mc_cov)


def test_execute_ukf_equals_kalman_on_linear_toy(rng, tol):
    sim, plan = _setup(rng, T=8)
    lin = linearize(sim, plan, sim.distribution, n_samples=32, seed=1)
    ctrl = lqg_controller(lin, P0=0.01 * np.eye(3))
    for k in range(3):
        params = sim.distribution.sample(np.random.default_rng(k))
        a = execute(sim, plan, ctrl, params, seed=10 + k)
        b = execute(sim, plan, ctrl, params, seed=10 + k, estimator="ukf")
        np.testing.assert_allclose(b.estimates, a.estimates, **tol["float64_ref"])
        np.testing.assert_allclose(b.controls, a.controls, **tol["float64_ref"])
        assert a.outcome == b.outcome
    with pytest.raises(InvalidInputError, match="estimator"):
        execute(sim, plan, ctrl, plan.params, estimator="particle")


def test_material_frame_measurement_is_the_sensed_world_position(tol):
    """The needle in its material frame: ``h_t(0) = 0``, ``h_t`` agrees with the EKF's
    ``H_t`` to first order (the error shrinks faster than ``ξ``), and the UKF's executions
    track the Kalman filter's without being identical to them."""
    import warnings

    from riskplan.control import NominalPlan, execute, linearize, lqg_controller
    from riskplan.control.greedy import greedy_needle_controls
    from riskplan.control.ukf import material_measurement
    from riskplan.scenarios.registry import make_scenario

    # actuation noise: the material pose is uncertain (P > 0); a material draw alone moves only
    # the measurement, so there P stays 0 and every filter is exact
    sim = make_scenario("needle", "actuation").with_frame("material")
    u = greedy_needle_controls(sim, sim.nominal_params, 40, speed=0.8)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    h = material_measurement(sim, plan)
    assert material_measurement(make_scenario("needle", "actuation"), plan) is None
    t = plan.n_steps // 2
    np.testing.assert_allclose(h(t, np.zeros(3)), 0.0, **tol["float64_abs"])
    H = sim.observation_jacobian(plan.states[t])
    xi = np.array([0.6, -0.8, 0.5]) * sim.config.goal_radius
    errs = [np.linalg.norm(h(t, xi * e) - H @ (xi * e)) / e for e in (0.1, 0.01)]
    assert errs[1] < 0.5 * errs[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ctrl = lqg_controller(linearize(sim, plan, sim.distribution, n_samples=8, seed=0))
    params = sim.distribution.sample(np.random.default_rng(3))
    ex_k = execute(sim, plan, ctrl, params, seed=5, estimator="kalman")
    ex_u = execute(sim, plan, ctrl, params, seed=5, estimator="ukf")
    gap = np.abs(np.asarray(ex_u.estimates) - np.asarray(ex_k.estimates)).max()
    assert 0.0 < gap < 0.1 * sim.config.goal_radius
