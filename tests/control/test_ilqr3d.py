"""iLQR's 3-D obstacle barrier: signed distances to ellipsoids and parallelepipeds against
closed forms and independent solvers, their gradients and the barrier's against finite
differences, and iLQR on the 3-D needle (strictly falling cost; a grazed obstacle left with
more clearance)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.optimize import lsq_linear, minimize

from riskplan.control.ilqr_cost3d import body_signed_distance, obstacle_barrier_3d
from riskplan.errors import InvalidInputError
from riskplan.geometry3d import ConvexBody, nearest_to_origin
from riskplan.scenarios.base import SimParams

SHEAR = np.array([[0.3, 0.05, 0.0], [0.0, 0.2, 0.04], [0.02, 0.0, 0.1]])


def _fd_grad(f, P, h=1e-6):
    g = np.zeros_like(P)
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        g[:, j] = (f(P + e) - f(P - e)) / (2 * h)
    return g


def _fd_grad_sum(f, P, h=1e-6):
    """Central differences of a scalar ``f`` of all points, one coordinate at a time."""
    g = np.zeros_like(P)
    for i in range(len(P)):
        for j in range(3):
            e = np.zeros_like(P)
            e[i, j] = h
            g[i, j] = (f(P + e) - f(P - e)) / (2 * h)
    return g


def _ellipsoid_boundary_distance(p, body):
    """Distance from p to the ellipsoid's surface by a local optimiser over the sphere's
    angles, started from the nearest of 20,000 surface samples."""
    u = body.surface(100)
    k = int(np.argmin(np.linalg.norm(u - p, axis=1)))
    s0 = body.local(u[k])
    th0 = [np.arccos(np.clip(s0[2], -1, 1)), np.arctan2(s0[1], s0[0])]

    def f(th):
        s = np.array([np.sin(th[0]) * np.cos(th[1]), np.sin(th[0]) * np.sin(th[1]), np.cos(th[0])])
        r = body.centre + body.A @ s - p
        return float(r @ r)

    res = minimize(f, th0, method="BFGS", options={"gtol": 1e-14})
    return np.sqrt(res.fun)


def _box_distance(p, body):
    """Outside: bounded least squares ``min |A s − (p − c)|``, |s_i| <= 1 (scipy); inside:
    the nearest of the six faces, each by bounded least squares on that face."""
    M, a = body.A, p - body.centre
    if body.norm(p) > 1.0:
        return lsq_linear(M, a, bounds=(-1, 1), tol=1e-14).cost ** 0.5 * np.sqrt(2)
    best = np.inf
    for k in range(3):
        for sgn in (-1.0, 1.0):
            free = [i for i in range(3) if i != k]
            r = a - sgn * M[:, k]
            res = lsq_linear(M[:, free], r, bounds=(-1, 1), tol=1e-14)
            best = min(best, np.linalg.norm(M[:, free] @ res.x - r))
    return -best


def test_sphere_and_axis_aligned_box_closed_forms(rng, tol):
    ball = ConvexBody("ellipsoid", np.ones(3), 0.5 * np.eye(3))
    P = rng.normal(size=(20, 3)) * 0.6 + 1.0
    d, n = body_signed_distance(P, ball)
    np.testing.assert_allclose(d, np.linalg.norm(P - 1.0, axis=1) - 0.5, **tol["float64_abs"])
    np.testing.assert_allclose(
        n, (P - 1.0) / np.linalg.norm(P - 1.0, axis=1)[:, None], **tol["float64_ref"]
    )
    h = np.array([1.0, 2.0, 3.0])
    box = ConvexBody("box", np.zeros(3), np.diag(h))
    P = rng.normal(size=(40, 3)) * 3.0
    d, _ = body_signed_distance(P, box)
    outside = np.linalg.norm(np.maximum(np.abs(P) - h, 0.0), axis=1)
    inside = np.minimum(np.max(np.abs(P) - h, axis=1), 0.0)
    np.testing.assert_allclose(d, outside + inside, **tol["float64_abs"])
    assert (d < 0).any() and (d > 0).any()
    # the centre of a ball (every surface point equally near) still gets a unit normal
    d0, n0 = body_signed_distance(np.ones((1, 3)), ball)
    assert d0[0] == pytest.approx(-0.5) and np.linalg.norm(n0[0]) == pytest.approx(1.0)


def test_sheared_bodies_against_independent_solvers(rng, tol):
    ell = ConvexBody("ellipsoid", np.array([0.1, -0.2, 0.3]), SHEAR)
    box = ConvexBody("box", np.array([0.1, -0.2, 0.3]), SHEAR)
    P = ell.centre + rng.normal(size=(24, 3)) * 0.25
    d, _ = body_signed_distance(P, ell)
    for p, di in zip(P, d):
        if ell.norm(p) > 1.0:  # outside: the whitened nearest point with L = I (Newton)
            ref, _ = nearest_to_origin(ell, np.eye(3), p)
        else:
            ref = -_ellipsoid_boundary_distance(p, ell)
        np.testing.assert_allclose(di, ref, **tol["solver"])
    assert (d < 0).sum() >= 3 and (d > 0).sum() >= 3
    d, _ = body_signed_distance(P, box)
    ref = np.array([_box_distance(p, box) for p in P])
    np.testing.assert_allclose(d, ref, **tol["solver"])
    assert (d < 0).sum() >= 3 and (d > 0).sum() >= 3


@pytest.mark.parametrize("kind", ["ellipsoid", "box"])
def test_gradient_is_the_outward_normal(rng, tol, kind):
    body = ConvexBody(kind, np.zeros(3), SHEAR)
    P = rng.normal(size=(30, 3)) * 0.25
    d, n = body_signed_distance(P, body)
    g = _fd_grad(lambda Q: body_signed_distance(Q, body)[0], P)
    # off the medial surface inside (a box's interior distance has kinks there): the two
    # nearest faces differ by more than the difference step
    if kind == "box":
        s = body.local(P)
        face = np.sort((1.0 - np.abs(s)) / np.linalg.norm(np.linalg.inv(SHEAR), axis=1), axis=1)
        keep = (d > 0) | (face[:, 1] - face[:, 0] > tol["fd_kink_margin"]["atol"])
        g, n = g[keep], n[keep]
    np.testing.assert_allclose(n, g, **tol["fd_jacobian"])
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, **tol["float64_abs"])


def test_barrier_derivatives_against_finite_differences(rng, tol):
    bodies = [
        ConvexBody("ellipsoid", np.zeros(3), SHEAR),
        ConvexBody("box", np.array([0.8, 0.0, 0.0]), 0.5 * SHEAR),
    ]
    w, delta = 2.0, 0.15
    P = np.array([[0.45, 0.1, 0.0], [0.0, 0.35, 0.1], [0.3, -0.2, 0.2], [1.2, 0.1, 0.05]])
    v, g, _ = obstacle_barrier_3d(P, bodies, w, delta)
    expected = sum(w * np.exp(-body_signed_distance(P, o)[0] / delta).sum() for o in bodies)
    np.testing.assert_allclose(v, expected, **tol["float64_exact"])
    np.testing.assert_allclose(
        g,
        _fd_grad_sum(lambda Q: obstacle_barrier_3d(Q, bodies, w, delta)[0], P),
        **tol["fd_jacobian"],
    )
    # one body at a time: differences of the analytic gradient (the full Hessian) equal the
    # Gauss–Newton form along n (∇²d n = 0), and exceed it nowhere outside (φ' ∇²d ⪯ 0)
    for o in bodies:
        d, n = body_signed_distance(P, o)
        _, _, Hg = obstacle_barrier_3d(P, [o], w, delta)
        for i in range(len(P)):
            Hfd = np.zeros((3, 3))
            for j in range(3):
                e = np.zeros((1, 3))
                e[0, j] = 1e-6
                gp = obstacle_barrier_3d(P[i : i + 1] + e, [o], w, delta)[1][0]
                gm = obstacle_barrier_3d(P[i : i + 1] - e, [o], w, delta)[1][0]
                Hfd[:, j] = (gp - gm) / 2e-6
            scale = float(np.abs(Hfd).max())
            np.testing.assert_allclose(
                n[i] @ Hfd @ n[i],
                n[i] @ Hg[i] @ n[i],
                rtol=tol["fd_hessian_scaled"]["rtol"],
                atol=tol["fd_hessian_scaled"]["atol"] * scale,
            )
            assert d[i] > 0
            gap = np.linalg.eigvalsh(0.5 * (Hfd + Hfd.T) - Hg[i])
            assert gap.max() <= tol["fd_hessian_scaled"]["atol"] * scale
            assert np.linalg.eigvalsh(Hg[i]).min() >= -tol["float64_abs"]["atol"] * scale
    with pytest.raises(InvalidInputError, match="barrier"):
        obstacle_barrier_3d(P, bodies, w, 0.0)
    with pytest.raises(InvalidInputError, match="ConvexBody"):
        body_signed_distance(P, SHEAR)


def test_trajectory_barrier_chain_rule(rng, tol):
    """The trajectory term with body weights (points interpolated between collision points)
    against finite differences in the reduced state."""
    from riskplan.control import NominalPlan
    from riskplan.control.ilqr_cost3d import make_barrier_3d

    T, p = 3, 7
    col = np.array([[0, 1, 2], [3, 4, 5]])
    ref = rng.normal(size=(T + 1, p)) * 0.3
    plan = NominalPlan(
        states=tuple(range(T + 1)), controls=np.zeros((T, 1)), reduced=ref, params=SimParams()
    )
    W = [rng.uniform(0.0, 1.0, (4, 2)) for _ in range(T + 1)]
    base = [rng.normal(size=(4, 3)) * 0.4 for _ in range(T + 1)]
    e = ConvexBody("ellipsoid", np.zeros(3), SHEAR)
    b = ConvexBody("box", np.array([0.5, 0.2, 0.0]), 0.5 * SHEAR)
    obst = [[], [e], [e, b], [b]]
    bar = make_barrier_3d(plan, obst, col, list(zip(base, W)), 1.5, 0.3)
    x = ref + 0.05 * rng.normal(size=ref.shape)
    _, bx, bxx = bar.terms(x)
    gfd = np.zeros_like(x)
    for t in range(T + 1):
        for i in range(p):
            d = np.zeros_like(x)
            d[t, i] = 1e-6
            gfd[t, i] = (bar.terms(x + d)[0] - bar.terms(x - d)[0]) / 2e-6
    np.testing.assert_allclose(bx, gfd, **tol["fd_jacobian"])
    assert np.all(bx[:, 6] == 0) and np.all(bx[0] == 0) and np.any(bx[1:])
    floor = tol["float64_exact"]["atol"]
    assert all(np.linalg.eigvalsh(h).min() >= -floor * max(1.0, np.abs(h).max()) for h in bxx)
    with pytest.raises(InvalidInputError, match="points"):
        make_barrier_3d(plan, obst, [[0, 1]], None, 1.0, 1.0)
    with pytest.raises(InvalidInputError, match="steps"):
        make_barrier_3d(plan, obst[:-1], col, None, 1.0, 1.0)


def _grazing_scene():
    """A 3-D needle with constant controls (an arc in the block) and one ball placed
    0.015 beside the arc's middle (in material coordinates, across the arc's plane); the
    target at the arc's end."""
    from riskplan.control import NominalPlan
    from riskplan.scenarios.needle3d import Needle3DConfig, Needle3DScenario
    from riskplan.scenarios.uncertainty import get_case

    T, u = 12, np.array([0.4, 0.0])
    free = Needle3DScenario(Needle3DConfig(obstacles=()))
    ys = [free.initial_state()]
    for _ in range(T):
        ys.append(free.step(ys[-1], u))
    mid, end = ys[T // 2].material, ys[-1].material
    r = 0.08
    centre = mid[:3] + (r + 0.015) * mid[3:6]  # e₁: across the plane the arc bends in
    cfg = Needle3DConfig(obstacles=(("sphere", tuple(centre), r),), target_center=tuple(end[:3]))
    sim = Needle3DScenario(cfg)
    sim.distribution = get_case("actuation", sim.nominal_params, actuation_cov=sim.actuation_cov())
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), np.tile(u, (T, 1)))
    return sim, plan


def test_barrier_moves_a_3d_plan_off_a_grazed_obstacle():
    """iLQR with the scenario's 3-D terms on a plan that passes 0.015 from a ball: every
    accepted iterate lowers the cost; with the barrier the re-optimised plan keeps more
    clearance from the deformed ball than the plan and than iLQR without it. The unit
    weights (w = 1, δ = the target radius 0.1) move it by about 0.0005 only (the tracking
    cost holds the bevel's roll as tightly as its pitch); w = 10, δ = 0.05 is used here to
    show the direction clearly (about 0.004)."""
    from riskplan.control.ilqr import ilqr
    from riskplan.control.ilqr_cost import scenario_terms
    from riskplan.control.linearize import RankDeficiencyWarning, linearize
    from riskplan.control.lqg import bryson_weights

    sim, plan = _grazing_scene()

    def clearance(pl):
        return min(
            body_signed_distance(y.pose[None, :3], o)[0][0]
            for y in pl.states[1:]
            for o in sim.obstacles(y)
        )

    assert 0.0 < clearance(plan) < 0.02
    terms = scenario_terms(sim, plan)
    assert len(terms["obstacles"]) == plan.n_steps + 1 and terms["points"] == ((0, 1, 2),)
    np.testing.assert_array_equal(terms["goal"][:3], sim.goal(plan.states[-1]).centre)
    assert terms["barrier_scale"] == pytest.approx(sim.config.target_radius)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RankDeficiencyWarning)
        lin = linearize(sim, plan, [plan.params], seed=0)
        Q = bryson_weights(lin.state_scale, np.ones(1))[0]
        R = bryson_weights(np.ones(1), lin.control_scale)[1]
        unit = ilqr(sim, plan, Q, R, max_iter=2, **terms)
        strong = ilqr(
            sim, plan, Q, R, max_iter=3, **{**terms, "barrier_weight": 10.0, "barrier_scale": 0.05}
        )
        none = ilqr(sim, plan, Q, R, max_iter=2, **{**terms, "obstacles": None})
    for res in (unit, strong):
        assert res.costs.size >= 2 and np.all(np.diff(res.costs) < 0)
    assert clearance(unit.plan) > clearance(plan)
    assert clearance(strong.plan) > clearance(plan) + 0.003
    assert clearance(strong.plan) > clearance(none.plan) + 0.003
