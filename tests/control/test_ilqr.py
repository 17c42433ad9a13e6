"""iLQR: one iteration to the optimum on a linear system (against LQR's gains and the
stacked least-squares solution), monotone cost on the needle."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.control import lqr_gains
from riskplan.control.ilqr import ilqr
from riskplan.errors import InvalidInputError

from .test_lqg import _setup


def _stacked_optimum(A, B, x0, ref_x, ref_u, Q, R, Qf, goal, Qg):
    """argmin_U of the quadratic cost by least squares on x = Φ x0 + Γ U."""
    T = ref_u.shape[0]
    p, q = B.shape
    Phi = [np.eye(p)]
    for _ in range(T):
        Phi.append(A @ Phi[-1])
    G = np.zeros((T + 1, p, T * q))
    for t in range(1, T + 1):
        for s in range(t):
            G[t, :, s * q : (s + 1) * q] = np.linalg.matrix_power(A, t - 1 - s) @ B
    rows, rhs = [], []
    for t in range(T + 1):
        W = Q if t < T else Qf
        C = np.linalg.cholesky(W + 1e-300 * np.eye(p)).T
        rows.append(C @ G[t])
        rhs.append(C @ (ref_x[t] - Phi[t] @ x0))
    Cg = np.linalg.cholesky(Qg).T
    rows.append(Cg @ G[T])
    rhs.append(Cg @ (goal - Phi[T] @ x0))
    Cr = np.linalg.cholesky(R).T
    for t in range(T):
        E = np.zeros((q, T * q))
        E[:, t * q : (t + 1) * q] = np.eye(q)
        rows.append(Cr @ E)
        rhs.append(Cr @ ref_u[t])
    U = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    return U.reshape(T, q)


def test_linear_one_iteration_is_lqr(rng, tol):
    sim, plan = _setup(rng, T=6, goal_half=5.0)  # a wide goal: the control bounds stay inactive
    T = plan.n_steps
    A, B = sim.A_true, sim.B_true
    Q, R, Qf = np.eye(3), 2.0 * np.eye(3), 3.0 * np.eye(3)
    goal, Qg = plan.reduced[-1] + np.array([0.3, -0.2, 0.1]), 5.0 * np.eye(3)

    def lin(_pl):
        return np.broadcast_to(A, (T, 3, 3)), np.broadcast_to(B, (T, 3, 3))

    res = ilqr(sim, plan, Q, R, Qf, goal, Qg, linearizer=lin, mu0=0.0, max_iter=3)
    U = _stacked_optimum(A, B, plan.reduced[0], plan.reduced, plan.controls, Q, R, Qf, goal, Qg)
    # later iterations find nothing left to gain beyond round-off: the first reached the optimum
    assert res.converged
    np.testing.assert_allclose(res.costs[1:], res.costs[1], **tol["float64_ref"])
    np.testing.assert_allclose(res.plan.controls, U, **tol["float64_ref"])
    L = lqr_gains(np.broadcast_to(A, (T, 3, 3)), np.broadcast_to(B, (T, 3, 3)), Q, R, Qf + Qg)
    np.testing.assert_allclose(res.K, L, **tol["float64_ref"])
    assert res.costs[1] < res.costs[0]


def test_default_linearizer_and_bad_input(rng):
    sim, plan = _setup(rng, T=5, goal_half=5.0)
    res = ilqr(sim, plan, np.eye(3), np.eye(3), goal=plan.reduced[-1] + 0.2, Q_goal=np.eye(3))
    assert np.all(np.diff(res.costs) < 0) and res.n_linearizations >= 1
    with pytest.raises(InvalidInputError, match="plan"):
        ilqr(sim, plan.controls, np.eye(3), np.eye(3))


def test_needle_cost_decreases_monotonically():
    import warnings

    from riskplan.control import NominalPlan, bryson_weights
    from riskplan.control.greedy import greedy_needle_controls
    from riskplan.control.linearize import RankDeficiencyWarning
    from riskplan.scenarios.registry import make_scenario

    sim = make_scenario("needle", "actuation")
    u = greedy_needle_controls(sim, sim.nominal_params, 40, speed=0.8)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    r = sim.config.goal_radius
    Q, R = bryson_weights(sim.state_scale, np.ones(2))[0], np.eye(2)
    goal = np.r_[sim.goal_center(plan.states[-1]), plan.reduced[-1, 2]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RankDeficiencyWarning)
        res = ilqr(
            sim, plan, Q, R, goal=goal, Q_goal=np.diag([10 / r**2, 10 / r**2, 0.0]), max_iter=3
        )
    assert res.costs.size >= 2 and np.all(np.diff(res.costs) < 0)
    d0 = np.linalg.norm(plan.reduced[-1, :2] - goal[:2])
    d1 = np.linalg.norm(res.plan.reduced[-1, :2] - goal[:2])
    assert d1 < d0


def test_tracking_controller_selects(rng):
    from riskplan.control.ilqr import tracking_controller

    sim, plan = _setup(rng, T=5, goal_half=5.0)
    p0, c0, info0 = tracking_controller(sim, plan, sim.distribution, controller="lqr")
    assert p0 is plan and info0 is None and c0.n_steps == plan.n_steps
    goal = plan.reduced[-1] + 0.2
    p1, c1, info1 = tracking_controller(
        sim, plan, sim.distribution, controller="ilqr", goal=goal, Q_goal=np.eye(3)
    )
    assert info1.costs[-1] < info1.costs[0] and p1 is info1.plan and c1.n_steps == p1.n_steps
    assert np.linalg.norm(p1.reduced[-1] - goal) < np.linalg.norm(plan.reduced[-1] - goal)
    with pytest.raises(InvalidInputError, match="controller"):
        tracking_controller(sim, plan, controller="ilqg")
