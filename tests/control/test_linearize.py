"""Numerical linearisation: exact A, B of a linear toy simulator, M within its Monte Carlo
tolerance, backend independence, rank deficiency and non-finite states, the needle's car Jacobian."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskplan.control import NominalPlan, linearize
from riskplan.control.linearize import RankDeficiencyWarning
from riskplan.errors import InvalidInputError, SimulationError
from tests.conftest import TOL

from .toy import FORCE, LinearToy, toy_system


def _plan(sim, rng, T=5):
    u = rng.uniform(-1, 1, (T, sim.control_dim))
    return NominalPlan.from_rollout(sim, sim.initial_state(), u)


def test_linear_toy_exact_A_B(rng, tol):
    A, B, c = toy_system(rng, p=3, q=3)
    sim = LinearToy(A, B, c)
    plan = _plan(sim, rng)
    lin = linearize(sim, plan, seed=1)
    assert lin.A.shape == (5, 3, 3) and lin.B.shape == (5, 3, 3) and lin.H.shape == (5, 2, 3)
    # finite differences of an affine map: exact up to rounding of x ~ 1 divided by ε ~ 0.02
    np.testing.assert_allclose(lin.A, np.broadcast_to(A, lin.A.shape), **tol["float64_ref"])
    np.testing.assert_allclose(lin.B, np.broadcast_to(B, lin.B.shape), **tol["float64_ref"])
    np.testing.assert_array_equal(lin.M, 0.0)
    np.testing.assert_array_equal(lin.H[0], sim.observation_matrix)
    assert (lin.rank == 3).all()


def test_linear_toy_M_within_monte_carlo_tolerance(rng):
    A, B, c = toy_system(rng, p=3, q=3)
    sim = LinearToy(A, B, c)
    plan = _plan(sim, rng, T=2)
    n = 2000
    lin = linearize(sim, plan, FORCE, n_samples=n, seed=2)
    M_true = np.outer(c, c) * FORCE.variance
    # the estimate is (mean of (f-1)²) c cᵀ; (f-1)² with f-1 ~ U[-1,1] has mean 1/3, variance 4/45
    rel_sd = math.sqrt(4 / 45) / (1 / 3) / math.sqrt(n)
    np.testing.assert_allclose(
        lin.M[0], lin.M[1], **TOL["float64_exact_small"]
    )  # same draws every step
    np.testing.assert_allclose(lin.M[0], M_true, rtol=4 * rel_sd, atol=TOL["float64_abs"]["atol"])


def test_actuation_noise_enters_M(rng):
    A, B, _ = toy_system(rng)
    sim = LinearToy(A, B)
    from riskplan.scenarios.uncertainty import ActuationNoise

    cov = np.diag([0.04, 0.01, 0.02])
    dist = ActuationNoise(cov=tuple(map(tuple, cov)))
    plan = _plan(sim, rng, T=1)
    n = 3000
    lin = linearize(sim, plan, dist, n_samples=n, seed=3)
    M_true = B @ cov @ B.T
    # second moment of a Gaussian: entrywise sd (M_ii M_jj + M_ij²)^(1/2) / sqrt(n)
    sd = np.sqrt((np.outer(np.diag(M_true), np.diag(M_true)) + M_true**2) / n)
    assert np.all(np.abs(lin.M[0] - M_true) < 4.5 * sd)


def test_same_seed_same_result_whatever_the_chunking(rng):
    # one seed per step: chunks of steps (as the process backends use) change nothing.
    # local with one worker runs the chunks in this process (no pool start-up in tests);
    # process pools are exercised by the Monte Carlo test in test_lqg.py
    A, B, c = toy_system(rng)
    sim = LinearToy(A, B, c)
    plan = _plan(sim, rng, T=6)
    a = linearize(sim, plan, FORCE, n_samples=8, seed=5, backend="serial")
    b = linearize(sim, plan, FORCE, n_samples=8, seed=5, backend="local", workers=1)
    for name in ("A", "B", "M"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    c2 = linearize(sim, plan, FORCE, n_samples=8, seed=6)
    assert not np.array_equal(a.M, c2.M)


def test_rank_deficient_warns_and_keeps_prior(tol):
    # x3 is never excited by the controls: X_t has rank 2
    A = np.array([[0.9, 0.1, 0.0], [0.0, 0.8, 0.0], [0.0, 0.0, 0.5]])
    B = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    sim = LinearToy(A, B)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), np.full((3, 2), 0.5))
    with pytest.warns(RankDeficiencyWarning, match="rank"):
        lin = linearize(sim, plan, seed=0)
    assert (lin.rank == 2).all()
    np.testing.assert_allclose(
        lin.A[:, :2, :2], np.broadcast_to(A[:2, :2], (3, 2, 2)), **tol["float64_ref"]
    )
    np.testing.assert_allclose(lin.A[:, 2, 2], 1.0, **tol["float64_exact"])  # identity prior
    with pytest.warns(RankDeficiencyWarning):
        lin0 = linearize(sim, plan, seed=0, a_prior="zero")
    np.testing.assert_allclose(
        lin0.A[:, 2, 2], 0.0, **tol["float64_abs"]
    )  # the paper's plain pseudo-inverse


def test_non_finite_state_names_step(rng):
    A, B, _ = toy_system(rng)
    sim = LinearToy(A, B)
    plan = _plan(sim, rng, T=4)
    bad = LinearToy(A, B, nan_at=3)
    with pytest.raises(SimulationError, match="step 3"):
        linearize(bad, plan, seed=0)


def test_bad_input(rng):
    A, B, _ = toy_system(rng)
    sim = LinearToy(A, B)
    plan = _plan(sim, rng, T=2)
    with pytest.raises(InvalidInputError, match="a_prior"):
        linearize(sim, plan, a_prior="one")
    with pytest.raises(InvalidInputError, match="W"):
        linearize(sim, plan, W=np.zeros((2, 2)))
    with pytest.raises(InvalidInputError, match="plan"):
        linearize(sim, "plan")
    with pytest.raises(InvalidInputError, match="n_a_runs"):
        linearize(sim, plan, n_a_runs=0)


def test_needle_matches_car_jacobian():
    # the needle's pose update is the paper's car (V-A): compare with its analytic Jacobian.
    # The Euler step moves the position along the old heading, so the A-runs never excite
    # the lateral direction (X_t has rank 2); the identity prior is exact there.
    from riskplan.scenarios.needle import NeedleScenario

    sim = NeedleScenario()
    u = sim.random_controls(8, seed=4)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    with pytest.warns(RankDeficiencyWarning, match="lowest rank 2"):
        lin = linearize(sim, plan, seed=0)
    cfg = sim.config
    k = 1.0 / (cfg.r_min * math.tan(cfg.phi_max))
    for t in range(1, 8):
        th = plan.reduced[t, 2]
        v, phi = plan.controls[t]
        A_true = np.array(
            [[1, 0, -cfg.tau * v * math.sin(th)], [0, 1, cfg.tau * v * math.cos(th)], [0, 0, 1]]
        )
        B_true = np.array(
            [
                [cfg.tau * math.cos(th), 0],
                [cfg.tau * math.sin(th), 0],
                [cfg.tau * math.tan(phi) * k, cfg.tau * v * k / math.cos(phi) ** 2],
            ]
        )
        np.testing.assert_allclose(lin.B[t], B_true, **TOL["needle_car_B"])
        np.testing.assert_allclose(lin.A[t], A_true, **TOL["needle_car_A"])
