"""Numerical linearisation: exact A, B of a linear toy simulator, M within its Monte Carlo
tolerance, backend independence, rank deficiency and non-finite states, the needle's car Jacobian."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from riskplan.control import NominalPlan, linearize
from riskplan.control.linearize import RankDeficiencyWarning
from riskplan.errors import InvalidInputError, SimulationError
from tests.conftest import TOL

from .toy import FORCE, LinearToy, toy_system


class Without:
    """``inner`` with the optional simulator hooks ``names`` hidden (as if not implemented)."""

    def __init__(self, inner, *names):
        self._inner, self._names = inner, names

    def __getattr__(self, name):
        if name in self.__dict__.get("_names", ()):
            raise AttributeError(name)
        return getattr(self.__dict__["_inner"], name)


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
    # without interaction force the tissue does not move, and the needle's pose update is
    # the paper's car (V-A): compare with its analytic Jacobian.
    # The Euler step moves the position along the old heading, so the A-runs never excite
    # the lateral direction (X_t has rank 2); the identity prior is exact there.
    from riskplan.scenarios.needle import NeedleScenario

    # The paper's K = 2p A-runs: the fit averages the car's curvature over the runs, and the
    # default K = 2q = 4 leaves about 1.6x its error (median over 8 seeds 4.6e-4 against
    # 2.8e-4 for K = 6, largest 2.0e-3 against 7.8e-4).
    sim = NeedleScenario()
    u = sim.random_controls(8, seed=4)
    free = sim.nominal_params.replace(force_scale=0.0)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(free), u, free)
    with pytest.warns(RankDeficiencyWarning, match="lowest rank 2"):
        lin = linearize(sim, plan, n_a_runs=2 * sim.state_dim, seed=0)
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


def test_needle_a_fit_keeps_the_first_order_span():
    """The needle's A-runs perturb 2 controls; with the tissue's second-order response the
    deviations reach full numerical rank, and a_max_rank keeps the fit on the 2 first-order
    directions (the identity prior elsewhere), so the LQR gains stay those of a car."""
    from riskplan.control import lqg_controller
    from riskplan.scenarios.needle import NeedleScenario

    sim = NeedleScenario()
    u = sim.random_controls(8, seed=4)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RankDeficiencyWarning)
        lin = linearize(sim, plan, n_a_runs=2 * sim.state_dim, seed=0)
        free = linearize(Without(sim, "a_max_rank"), plan, n_a_runs=2 * sim.state_dim, seed=0)
    assert lin.rank.max() == 2 and free.rank.max() == 3
    # the fitted third direction rests on second-order deviations: it inflates the gains
    # (here 37 against 9.3; on a paper-scale plan, with the deformed heading, 10^5)
    capped, uncapped = np.abs(lqg_controller(lin).L).max(), np.abs(lqg_controller(free).L).max()
    assert capped < uncapped


def test_k_2q_gives_the_same_A_as_2p_on_a_linear_system(rng):
    # p = 6 > q = 2: the A-runs excite only span(B), for any K; the fit there is exact and
    # the identity prior fills the rest, so K = 2q (the default) and the paper's K = 2p agree
    p, q = 6, 2
    A, B, c = toy_system(rng, p=p, q=q)
    sim = LinearToy(A, B, c)
    plan = _plan(sim, rng, T=4)
    with pytest.warns(RankDeficiencyWarning, match="lowest rank 2"):
        default = linearize(sim, plan, seed=3)
    with pytest.warns(RankDeficiencyWarning):
        k2q = linearize(sim, plan, n_a_runs=2 * q, seed=3)
    np.testing.assert_array_equal(default.A, k2q.A)  # the default is K = 2 min(p, q)
    Pb = B @ np.linalg.pinv(B)  # projection onto span(B)
    expected = np.eye(p) + (A - np.eye(p)) @ Pb
    for K, seed in ((2 * q, 4), (2 * p, 3), (2 * p, 5)):
        with pytest.warns(RankDeficiencyWarning):
            lin = linearize(sim, plan, n_a_runs=K, seed=seed)
        np.testing.assert_allclose(
            lin.A, np.broadcast_to(expected, lin.A.shape), **TOL["float64_ref"]
        )
        np.testing.assert_allclose(lin.A, default.A, **TOL["float64_ref"])
        np.testing.assert_array_equal(lin.B, default.B)  # B does not use the A-runs
        assert (lin.rank[1:] == q).all()


@pytest.mark.filterwarnings("ignore::riskplan.control.linearize.RankDeficiencyWarning")
def test_manipulation_k_2q_and_2p_and_solver_start(tol):
    # forces in the state: A_t = [[0, J], [0, I]] (the simulator's prior, exact), corrected
    # by the runs on the q first-order directions only, so K = 2q and K = 2p agree with the
    # exact structure to second order in the perturbation; B and M do not depend on K.
    # Starting the solves near the plan's states (step_near) changes B and M by no more than
    # the solver tolerance.
    from riskplan.scenarios.manipulation import ManipulationScenario
    from riskplan.scenarios.uncertainty import get_case

    sim = ManipulationScenario()
    case = get_case("material-high")
    u = sim.random_controls(3, seed=2)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    draws = case.sample_many(3, 7)
    draws = [d.replace(n_elements=plan.params.n_elements) for d in draws]
    q, p = sim.control_dim, sim.state_dim
    lins = {K: linearize(sim, plan, draws, n_a_runs=K, seed=1) for K in (2 * q, 2 * p)}
    for K, lin in lins.items():
        assert (lin.rank[1:] == q).all()
        for t in range(1, plan.n_steps):
            exact = sim.a_prior(plan.states[t + 1], plan.params)
            # second order in the perturbation (1 % of the increment range)
            assert np.abs(lin.A[t] - exact).max() <= 1e-2 * np.abs(exact).max(), K
    np.testing.assert_array_equal(lins[2 * q].B, lins[2 * p].B)
    np.testing.assert_array_equal(lins[2 * q].M, lins[2 * p].M)

    plain = linearize(Without(sim, "step_near"), plan, draws, n_a_runs=2 * q, seed=1)
    # each run's equilibrium within the solver's tolerance (newton_paths) of the other's:
    # B's forward differences then differ by at most 2 · 1e-8 / ε
    eps = 1e-3 * 2 * sim.config.df_max
    atol_B = 2 * TOL["newton_paths"]["atol"] / eps
    np.testing.assert_allclose(lins[2 * q].B, plain.B, rtol=0.0, atol=atol_B)
    np.testing.assert_allclose(lins[2 * q].M, plain.M, **TOL["solver_start_M"])


@pytest.mark.filterwarnings("ignore::riskplan.control.linearize.RankDeficiencyWarning")
def test_simulator_declared_prior_is_the_default():
    # ManipulationScenario declares its exact A structure as a method (a_prior(y, params));
    # linearize uses it by default, an explicit a_prior still wins. With the identity prior
    # the unexcited position directions would persist (wrong: the next equilibrium forgets
    # them); with the declared one they map to (near) zero, and the LQR gains are non-zero
    # (forces persist, so feedback has something to act on).
    from riskplan.control import lqg_controller
    from riskplan.scenarios.manipulation import ManipulationScenario

    sim = ManipulationScenario()
    assert callable(sim.a_prior)
    u = sim.random_controls(3, seed=2)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    default = linearize(sim, plan, [], seed=1)
    declared = linearize(sim, plan, [], a_prior=sim.a_prior, seed=1)
    ident = linearize(sim, plan, [], a_prior="identity", seed=1)
    np.testing.assert_array_equal(default.A, declared.A)
    n = 2 * sim.n_points
    for t in range(1, plan.n_steps):
        assert np.trace(ident.A[t][:n, :n]) > 0.5 * (
            sim.state_dim - ident.rank[t] - sim.control_dim
        )
        # second order in the perturbation (1 % of the increment range)
        np.testing.assert_allclose(default.A[t][:, :n], 0.0, **TOL["linearize_second_order"])
        np.testing.assert_allclose(
            default.A[t][n:, n:], np.eye(sim.control_dim), **TOL["linearize_second_order"]
        )
    L = lqg_controller(default).L
    assert np.all(np.abs(L).max(axis=(1, 2)) > 0.1)
    with pytest.raises(InvalidInputError, match="a_prior"):
        linearize(sim, plan, [], a_prior=lambda y, params: np.eye(3), seed=1)


@pytest.mark.filterwarnings("ignore::riskplan.control.linearize.RankDeficiencyWarning")
def test_mesh_draws_enter_M_through_transfer_state(tol):
    # The manipulation can move a stored state onto another mesh (quasi-static: any start
    # gives the same equilibrium), so the mesh case's draws run on their own meshes and M_t
    # is not zero; a simulator without transfer_state runs them on the plan's mesh (M = 0).
    from riskplan.scenarios.base import SimParams, rollout
    from riskplan.scenarios.manipulation import ManipulationScenario

    sim = ManipulationScenario()
    u = sim.random_controls(3, seed=2)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    other = SimParams(n_elements=400)
    # oracle: a step from the transferred state equals the same step of a rollout on that mesh
    direct = rollout(sim, sim.initial_state(other), u[:2], other)[-1]
    moved = sim.transfer_state(plan.states[1], other)
    assert moved.n_elements == 400 and moved.t == 1
    np.testing.assert_allclose(
        sim.reduced(sim.step(moved, u[1], other)), sim.reduced(direct), **tol["newton_paths"]
    )

    draws = [SimParams(n_elements=n) for n in (60, 400)]
    with_mesh = linearize(sim, plan, draws, seed=1)
    without = linearize(Without(sim, "transfer_state"), plan, draws, seed=1)
    np.testing.assert_array_equal(without.M, 0.0)
    # oracle: M_t from rollouts of the plan's controls on each draw's own mesh
    runs = [rollout(sim, sim.initial_state(d), u, d) for d in draws]
    for t in range(plan.n_steps):
        D = np.array([sim.reduced(r[t + 1]) for r in runs]) - plan.reduced[t + 1]
        atol = 4 * np.abs(D).max() * tol["newton_paths"]["atol"]
        np.testing.assert_allclose(with_mesh.M[t], D.T @ D / len(draws), rtol=0.0, atol=atol)
        assert np.trace(with_mesh.M[t]) > 0
