"""iLQR: one iteration to the optimum on a linear system (against LQR's gains and the
stacked least-squares solution), monotone cost on the needle."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.control import lqr_gains
from riskplan.control.ilqr import ilqr
from riskplan.errors import InvalidInputError

from .test_lqg import _setup
from .toy import square


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


# ---- the obstacle barrier -------------------------------------------------------------------


def _square_distance(p, h=1.0):
    """Closed-form signed distance of points to the square [−h, h]²."""
    q = np.abs(p) - h
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside


def _fd_grad(f, P, h=1e-6):
    g = np.zeros_like(P)
    for i in range(P.shape[0]):
        for j in range(2):
            e = np.zeros_like(P)
            e[i, j] = h
            g[i, j] = (f(P + e) - f(P - e)) / (2 * h)
    return g


def test_signed_distance_closed_form(tol):
    from riskplan.control.ilqr_cost import signed_distance

    sq = square(0.0, 0.0, 1.0)
    P = np.array([[1.5, 0.2], [2.0, 2.5], [-1.3, -1.4], [0.2, -0.5], [0.9, 0.0], [0.0, 3.0]])
    d, n, at_vertex = signed_distance(P, sq)
    np.testing.assert_allclose(d, _square_distance(P), **tol["float64_abs"])
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, **tol["float64_abs"])
    assert at_vertex.tolist() == [False, True, True, False, False, False]
    # the normal is the distance's gradient
    g = _fd_grad(lambda Q: _square_distance(Q).sum(), P)
    np.testing.assert_allclose(n, g, **tol["fd_jacobian"])


def test_barrier_derivatives_against_finite_differences(rng, tol):
    from riskplan.control.ilqr_cost import obstacle_barrier, signed_distance

    polys = [square(0.0, 0.0, 1.0), square(3.0, 0.5, 0.5)]
    w, delta = 2.0, 0.4
    # points off the medial axes: beside edges, beyond corners, one inside
    P = np.array([[1.3, 0.1], [1.6, 1.7], [-1.2, 0.4], [2.0, -0.8], [0.3, 0.6], [3.9, 1.4]])

    def value(Q):
        return obstacle_barrier(Q, polys, w, delta)[0]

    v, g, H = obstacle_barrier(P, polys, w, delta)
    expected = sum(w * np.exp(-signed_distance(P, o)[0] / delta).sum() for o in polys)
    np.testing.assert_allclose(v, expected, **tol["float64_exact"])
    np.testing.assert_allclose(g, _fd_grad(value, P), **tol["fd_jacobian"])
    # Hessian: central differences of the analytic gradient; the Gauss–Newton form omits
    # φ'(d) (I − n nᵀ) / d where the nearest boundary point is a vertex (zero along an edge)
    for i in range(len(P)):
        Hfd = np.zeros((2, 2))
        for j in range(2):
            e = np.zeros_like(P)
            e[i, j] = 1e-6
            Hfd[:, j] = (
                obstacle_barrier(P + e, polys, w, delta)[1][i]
                - obstacle_barrier(P - e, polys, w, delta)[1][i]
            ) / 2e-6
        curv = np.zeros((2, 2))
        for o in polys:
            d, n, vert = signed_distance(P[i : i + 1], o)
            if vert[0]:
                dphi = -w * np.exp(-d[0] / delta) / delta
                curv += dphi * (np.eye(2) - np.outer(n[0], n[0])) / d[0]
        np.testing.assert_allclose(H[i] + curv, Hfd, **tol["fd_jacobian"])
        assert np.all(np.linalg.eigvalsh(H[i]) >= 0.0)
    with pytest.raises(InvalidInputError, match="barrier"):
        obstacle_barrier(P, polys, w, 0.0)


def test_barrier_over_trajectory_chain_rule(rng, tol):
    """The trajectory term with outline weights (points interpolated between collision
    points) against finite differences in the reduced state."""
    from riskplan.control.ilqr_cost import _Barrier

    T, p = 3, 6
    col = np.array([[0, 1], [2, 3]])
    ref = rng.normal(size=(T + 1, p))
    W = [rng.uniform(0.0, 1.0, (5, 2)) for _ in range(T + 1)]
    base = [rng.normal(size=(5, 2)) * 2.0 for _ in range(T + 1)]
    obst = [(), (square(0.0, 0.0, 0.5),), (square(0.5, 1.0, 0.3), square(-2, 0, 1)), ()]
    bar = _Barrier(tuple(obst), col, tuple(base), tuple(W), ref, 1.5, 0.7)
    x = ref + 0.1 * rng.normal(size=ref.shape)
    _, bx, bxx = bar.terms(x)
    gfd = np.zeros_like(x)
    for t in range(T + 1):
        for i in range(p):
            e = np.zeros_like(x)
            e[t, i] = 1e-6
            gfd[t, i] = (bar.terms(x + e)[0] - bar.terms(x - e)[0]) / 2e-6
    np.testing.assert_allclose(bx, gfd, **tol["fd_jacobian"])
    # the batched evaluation (equal vertex counts) against the per-step loop
    loop = _Barrier(tuple(obst), col, tuple(base), tuple(W), ref, 1.5, 0.7)
    object.__setattr__(loop, "_stack", None)
    for a, b in zip(loop.terms(x), bar.terms(x)):
        np.testing.assert_allclose(a, b, **tol["float64_exact"])
    assert np.all(bx[:, 4:] == 0) and np.all(bx[0] == 0)
    assert all(np.all(np.linalg.eigvalsh(h) >= -tol["float64_abs"]["atol"]) for h in bxx)


def test_barrier_moves_the_plan_away_and_cost_decreases(rng):
    """A square obstacle placed beside the linear toy's plan: iLQR with the barrier ends
    farther from it than iLQR without, every accepted iterate lowers the cost."""
    from riskplan.control.ilqr_cost import signed_distance

    sim, plan = _setup(rng, T=6, goal_half=5.0)
    T = plan.n_steps
    mid = plan.reduced[T // 2, :2]
    obst = square(mid[0] + 0.12, mid[1], 0.1)  # 0.02 beside the plan's middle point
    A, B = sim.A_true, sim.B_true

    def lin(_pl):
        return np.broadcast_to(A, (T, 3, 3)), np.broadcast_to(B, (T, 3, 3))

    Q, R = np.eye(3), np.eye(3)

    def clearance(pl):
        return min(signed_distance(pl.reduced[1:, :2], obst)[0])

    base = ilqr(sim, plan, Q, R, linearizer=lin, max_iter=5)
    res = ilqr(
        sim,
        plan,
        Q,
        R,
        linearizer=lin,
        max_iter=8,
        obstacles=[[obst]] * (T + 1),
        barrier_weight=1.0,
        barrier_scale=0.05,
    )
    assert res.costs.size >= 2 and np.all(np.diff(res.costs) < 0)
    assert clearance(res.plan) > clearance(base.plan) + 0.02
    with pytest.raises(InvalidInputError, match="obstacles"):
        ilqr(sim, plan, Q, R, linearizer=lin, obstacles=[[obst]] * T)


def test_needle_scenario_terms():
    import warnings

    from riskplan.control import NominalPlan
    from riskplan.control.greedy import greedy_needle_controls
    from riskplan.control.ilqr import tracking_controller
    from riskplan.control.ilqr_cost import scenario_terms, signed_distance
    from riskplan.control.linearize import RankDeficiencyWarning
    from riskplan.scenarios.registry import make_scenario

    sim = make_scenario("needle", "actuation")
    u = greedy_needle_controls(sim, sim.nominal_params, 40, speed=0.8)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    terms = scenario_terms(sim, plan)
    # the deformed goal polygon's vertex mean and mean radius: the goal disk's, deformed
    r = sim.config.goal_radius
    assert np.linalg.norm(terms["goal"][:2] - sim.goal_center(plan.states[-1])) < 0.05 * r
    assert abs(np.sqrt(10.0 / terms["Q_goal"][0, 0]) / r - 1.0) < 0.05

    def clearance(pl):
        return min(
            min(signed_distance(pl.reduced[t : t + 1, :2], o)[0][0] for o in sim.obstacles(y))
            for t, y in enumerate(pl.states)
        )

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RankDeficiencyWarning)
        p1, _, info = tracking_controller(
            sim, plan, sim.distribution, controller="ilqr", terms=terms, max_iter=3
        )
        p0, _, _ = tracking_controller(
            sim, plan, sim.distribution, controller="ilqr", terms={**terms, "obstacles": None}
        )
    assert info.costs.size >= 2 and np.all(np.diff(info.costs) < 0)
    # the goal term pulls towards the goal's centre; the barrier keeps more clearance
    assert clearance(p1) > clearance(p0)
