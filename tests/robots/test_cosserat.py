"""Cosserat statics against independent oracles: closed-form arc, RK4 convergence rate,
equilibrium residuals, an independent scipy solve_bvp of Rucker & Webster's ODE, gravity
closed forms, rigid base pose."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from riskplan.robots import TendonRobot, load_robot, robot_from_toml
from riskplan.robots import cosserat as C
from riskplan.robots.integration import pose_from_node_strains
from riskplan.robots.linalg6 import chol_factor6
from riskplan.robots.rod_tables import LOCAL_MAXIT, LOCAL_TOL
from riskplan.robots.strains import strain_slope
from tests.conftest import TOL
from tests.robots.reference_kernels import shape_free_exact_midpoints, strains_along
from tests.robots.test_robot import FOUR_INEXTENSIBLE


@pytest.fixture(scope="module")
def paper():
    return load_robot("paper")


def with_step(robot, step, **backbone):
    bb = replace(robot.params.backbone, step=step, **backbone)
    return TendonRobot(replace(robot.params, backbone=bb))


def test_base_curvature_check_value(paper):
    """DESIGN.md check: one straight tendon, tau = 1 N -> base curvature tau r / (E I) = 1.3819 1/m."""
    x = strains_along(
        np.array([1.0, 0, 0, 0]),
        paper._theta,
        paper._radius,
        paper.tables.kse,
        paper.tables.kbt,
        [0.0],
    )
    np.testing.assert_allclose(x[0, 4], 1.3819, **TOL["quoted_5_digits"])
    np.testing.assert_allclose(
        x[0, 4], 0.008 / paper.params.backbone.kbt[0], **TOL["float64_exact_rel"]
    )


@pytest.mark.parametrize("tau", [1.0, 7.5])
def test_single_straight_tendon_is_circular_arc(paper, tau):
    """Closed form with shear/extension: u = (0, tau r/EI, 0) and v = (0, 0, 1 - tau/EA) are
    constant, so R(s) = Ry(k s) and p(s) = v3 ((1 - cos k s)/k, 0, sin(k s)/k)."""
    robot = with_step(paper, 0.0005)  # 400 steps
    shape = robot.solve_tensions([tau, 0, 0, 0])
    bb = robot.params.backbone
    k = tau * 0.008 / bb.kbt[0]
    v3 = 1.0 - tau / bb.kse[2]
    s = shape.s
    exact = v3 * np.stack([(1 - np.cos(k * s)) / k, 0 * s, np.sin(k * s) / k], -1)
    err = np.abs(shape.positions - exact).max() / bb.length
    assert err <= TOL["rk4_closed_form"]["atol"]
    Ry = np.stack([np.cos(k * s), 0 * s, -np.sin(k * s)], -1)  # first column of Ry(k s)
    np.testing.assert_allclose(shape.rotations[:, :, 0], Ry, **TOL["rk4_closed_form"])


def test_rk4_fourth_order_convergence(paper):
    """Tip error against a fine reference shrinks ~16x per halving of the step (helical + straight)."""
    tau = [2.0, 0.0, 1.0, 6.0]
    ref = with_step(paper, 0.2 / 640).solve_tensions(tau)
    errs = []
    for n in (10, 20, 40):
        shp = with_step(paper, 0.2 / n).solve_tensions(tau)
        errs.append(np.abs(shp.tip - ref.tip).max())
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(rates > 3.6), (errs, rates)


def test_equilibrium_residuals(paper):
    """Eqs. (2)-(3) hold at every station of the solution, and rotations stay orthonormal."""
    tau = np.array([3.0, 0.5, 0.0, 8.0])
    n = paper.n_stations - 1
    P = np.empty((n + 1, 3))
    R = np.empty((n + 1, 3, 3))
    X = np.empty((n + 1, 6))
    L = np.empty(4)
    assert C.shape_free(tau, *paper.tables, 1e-12, 50, P, R, X, L) == C.OK
    F = np.empty(6)
    z = np.zeros(3)
    for k in range(n + 1):
        e = C.local_residual(
            X[k],
            tau,
            paper.tables.offsets[2 * k],
            paper.tables.offset_slopes[2 * k],
            z,
            z,
            paper.tables.kse,
            paper.tables.kbt,
            F,
        )
        assert e <= TOL["strain_residual"]["atol"]
    np.testing.assert_allclose(
        np.einsum("nji,njk->nik", R, R),
        np.broadcast_to(np.eye(3), R.shape),
        **TOL["rk4_closed_form"],
    )


def test_hermite_midpoints_match_exact_midpoint_solves(paper):
    """Fast kernel (strains solved at the step nodes, Hermite midpoints) == reference kernel
    (strains solved at the half steps too): O(h^4) apart, and both converge to the same shape."""
    tau = np.array([4.0, 0.0, 1.0, 12.0])

    def run(robot, fn):
        n = robot.n_stations - 1
        P, R, X, L = (
            np.empty((n + 1, 3)),
            np.empty((n + 1, 3, 3)),
            np.empty((n + 1, 6)),
            np.empty(4),
        )
        assert fn(tau, *robot.tables, 1e-12, 50, P, R, X, L) == C.OK
        return P, L

    diffs, ldiffs = [], []
    for n in (20, 40, 80):
        r = with_step(paper, 0.2 / n)
        Pf, Lf = run(r, C.shape_free)
        Pr, Lr = run(r, shape_free_exact_midpoints)
        diffs.append(np.abs(Pf - Pr).max())
        ldiffs.append(np.abs(Lf - Lr).max())
    assert (
        diffs[1] < TOL["hermite_midpoints"]["atol"]
        and diffs[0] / diffs[1] > 10
        and diffs[1] / diffs[2] > 10
    ), diffs
    assert (
        ldiffs[1] < TOL["hermite_midpoints_length"]["atol"]
        and ldiffs[0] / ldiffs[1] > 10
        and ldiffs[1] / ldiffs[2] > 10
    ), ldiffs


def _node_strain_pose(robot, tau):
    """The displacement solve's shape pass at ``tau``: the length pass's node strains (eqs.
    (2)-(3) solved at every RK4 node), integrated by ``pose_from_node_strains``."""
    n, m = robot.n_stations - 1, robot.n_tendons
    xs, P, R = np.empty((2 * n + 1, 6)), np.empty((n + 1, 3)), np.empty((n + 1, 3, 3))
    st = C.lengths_and_jacobian(
        tau, *robot.tables, LOCAL_TOL, LOCAL_MAXIT, np.empty(m), np.empty((m, m)), xs
    )
    assert st == C.OK
    pose_from_node_strains(xs, robot.params.backbone.length / n, n, P, R)
    return P, R


def test_displacement_shape_is_the_pose_of_its_last_length_pass(paper):
    """``solve_displacements``' shape is, to the bit, the node-strain pass at the tensions it
    returns (the solve's last length pass is at them), batch and single, slack tendons and
    tensions over the limit included (batch vs single: ``test_robot.py``'s batch-equals-loop); and it is ``shape_free``'s shape at those tensions up to
    the two passes' O(h^4) difference (measured bound: TOL["node_strain_shape"])."""
    rng = np.random.default_rng(5)
    lim = paper.displacement_limits
    d = np.vstack(
        [
            rng.uniform(lim[:, 0], lim[:, 1], (30, 4)),
            [[-0.01, 0, 0, 0], [0.04, 0, 0, 0], [0.02, -0.01, -0.01, -0.01], [0, 0, 0, 0]],
        ]
    )
    shape = paper.solve_displacements(d)
    for b in range(len(d)):
        P, R = _node_strain_pose(paper, shape.tensions[b])
        np.testing.assert_array_equal(shape.positions[b], P)
        np.testing.assert_array_equal(shape.rotations[b], R)
        # one configuration (the scalar kernel; its start tau0 = A0^+ d rounds apart from the
        # batch's matrix product, so its tensions may differ from the batch's in the last bits)
        one = paper.solve_displacements(d[b])
        np.testing.assert_array_equal(one.positions, _node_strain_pose(paper, one.tensions)[0])
    ref = paper.solve_tensions(shape.tensions, validate=False)
    np.testing.assert_allclose(shape.positions, ref.positions, **TOL["node_strain_shape"])
    np.testing.assert_allclose(shape.rotations, ref.rotations, **TOL["node_strain_rotations"])


def test_displacement_shape_after_the_fischer_burmeister_switch():
    """Inextensible antagonistic tendons: these solves stall in min-function form and continue
    in Fischer-Burmeister form (all three do, seen with the kernels' Python source), whose
    re-evaluation at ``tau`` or later accepted steps are then the last length passes; the shape
    is still the node-strain pass at the returned tensions, to the bit."""
    robot = robot_from_toml(FOUR_INEXTENSIBLE)
    for d in ([0.005, 0.0, 0.0, 0.0], [0.01, 0.0, 0.0, 0.005], [0.02, 0.0, 0.01, 0.0]):
        shape = robot.solve_displacements(d)
        P, R = _node_strain_pose(robot, shape.tensions)
        np.testing.assert_array_equal(shape.positions, P)
        np.testing.assert_array_equal(shape.rotations, R)


def test_node_strain_pass_converges_at_fourth_order(paper):
    """The node-strain pass against a fine reference (``shape_free``, n = 640): the tip error
    shrinks ~16x per halving of the step, and with solved midpoints it is no less accurate
    than ``shape_free``'s Hermite midpoints at the robot's n = 40."""
    tau = np.array([2.4, 0.0, 0.6, 7.2])
    ref = with_step(paper, 0.2 / 640).solve_tensions(tau).tip
    errs = []
    for n in (10, 20, 40):
        P, _ = _node_strain_pose(with_step(paper, 0.2 / n), tau)
        errs.append(np.abs(P[-1] - ref).max())
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(rates > 3.6), (errs, rates)
    assert errs[-1] <= np.abs(paper.solve_tensions(tau).tip - ref).max(), errs


def test_strain_slope_matches_finite_differences(paper):
    """x'(s) from the implicit function theorem (R&W's ODE) == finite differences of local solves."""
    tau = np.array([2.0, 0.5, 0.0, 9.0])
    s = np.array([0.1 - 1e-6, 0.1, 0.1 + 1e-6])
    X = strains_along(
        tau, paper._theta, paper._radius, paper.tables.kse, paper.tables.kbt, s, tol=1e-14
    )
    fd = (X[2] - X[0]) / 2e-6
    th, rc = paper._theta, paper._radius
    rt, drt, ddrt = C.tendon_offset_table(th, rc, 0.2, 1)  # nodes at 0, 0.1, 0.2
    Lf = np.empty((6, 6))
    C.local_jacobian(X[1], tau, rt[1], drt[1], paper.tables.kse, paper.tables.kbt, Lf)
    assert chol_factor6(Lf)
    d = np.empty(6)
    strain_slope(X[1], tau, rt[1], drt[1], ddrt[1], Lf, d)
    np.testing.assert_allclose(d, fd, **TOL["fd_strain_slope"])


def test_jacobian_matches_finite_differences(paper, rng):
    tau = np.array([3.0, 0.0, 1.0, 8.0])
    x = np.array([0.01, -0.02, 0.99, 3.0, -5.0, 1.0])
    rt, drt = paper.tables.offsets[17], paper.tables.offset_slopes[17]
    J = np.empty((6, 6))
    C.local_jacobian(x, tau, rt, drt, paper.tables.kse, paper.tables.kbt, J)
    F0, F1 = np.empty(6), np.empty(6)
    z = np.zeros(3)
    Jfd = np.empty((6, 6))
    for j in range(6):
        h = 1e-7
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        C.local_residual(xp, tau, rt, drt, z, z, paper.tables.kse, paper.tables.kbt, F0)
        C.local_residual(xm, tau, rt, drt, z, z, paper.tables.kse, paper.tables.kbt, F1)
        Jfd[:, j] = (F0 - F1) / (2 * h)
    np.testing.assert_allclose(J, Jfd, **TOL["fd_jacobian"])


def _hat(w):
    """Skew matrices of vectors ``w (..., 3)`` -> ``(..., 3, 3)``."""
    z = np.zeros_like(w[..., 0])
    return np.stack(
        [
            np.stack([z, -w[..., 2], w[..., 1]], -1),
            np.stack([w[..., 2], z, -w[..., 0]], -1),
            np.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )


def _rw_bvp(robot, tau, guess_n=41):
    """Rucker & Webster 2011 eqs. (13)-(19) (no external load) solved with scipy's solve_bvp:
    states p, R, v, u; p(0) = 0, R(0) = I; tip condition R&W eq. (17). Written from the paper,
    sharing nothing with riskplan.robots.cosserat (vectorised over the mesh nodes)."""
    from scipy.integrate import solve_bvp

    bb = robot.params.backbone
    Kse, Kbt = np.diag(bb.kse), np.diag(bb.kbt)
    tendons = robot.params.tendons
    P = np.polynomial.polynomial
    e3 = np.array([0.0, 0.0, 1.0])

    def routing(s):
        s = np.atleast_1d(s)
        out = []
        for t in tendons:
            d1 = P.polyder(t.theta) if len(t.theta) > 1 else [0.0]
            d2 = P.polyder(t.theta, 2) if len(t.theta) > 2 else [0.0]
            r1 = P.polyder(t.radius) if len(t.radius) > 1 else [0.0]
            r2 = P.polyder(t.radius, 2) if len(t.radius) > 2 else [0.0]
            th, dth, ddth = P.polyval(s, t.theta), P.polyval(s, d1), P.polyval(s, d2)
            rho, drho, ddrho = P.polyval(s, t.radius), P.polyval(s, r1), P.polyval(s, r2)
            c, sn, z = np.cos(th), np.sin(th), 0 * s
            r = np.stack([rho * c, rho * sn, z], -1)
            dr = np.stack([drho * c - rho * sn * dth, drho * sn + rho * c * dth, z], -1)
            ddr = np.stack(
                [
                    ddrho * c - 2 * drho * sn * dth - rho * c * dth**2 - rho * sn * ddth,
                    ddrho * sn + 2 * drho * c * dth - rho * sn * dth**2 + rho * c * ddth,
                    z,
                ],
                -1,
            )
            out.append((r, dr, ddr))
        return out

    def rhs(s, Y):
        K = Y.shape[1]
        R = Y[3:12].T.reshape(K, 3, 3)
        v, u = Y[12:15].T, Y[15:18].T
        uh = _hat(u)
        A = np.zeros((K, 3, 3))
        G = np.zeros((K, 3, 3))
        B = np.zeros((K, 3, 3))
        H = np.zeros((K, 3, 3))
        a = np.zeros((K, 3))
        b = np.zeros((K, 3))
        for ti, (r, dr, ddr) in zip(tau, routing(s)):
            pd = np.einsum("kij,kj->ki", uh, r) + dr + v
            npd = np.linalg.norm(pd, axis=-1)[:, None, None]
            Ai = -ti * _hat(pd) @ _hat(pd) / npd**3
            Gi = -Ai @ _hat(r)
            ai = np.einsum(
                "kij,kj->ki",
                Ai,
                np.einsum("kij,kj->ki", uh, pd) + np.einsum("kij,kj->ki", uh, dr) + ddr,
            )
            A += Ai
            G += Gi
            B += _hat(r) @ Ai
            H += _hat(r) @ Gi
            a += ai
            b += np.einsum("kij,kj->ki", _hat(r), ai)
        c = (
            -np.einsum("kij,kj->ki", uh, u @ Kbt)
            - np.einsum("kij,kj->ki", _hat(v), (v - e3) @ Kse)
            - b
        )
        d = -np.einsum("kij,kj->ki", uh, (v - e3) @ Kse) - a
        M = np.concatenate([np.concatenate([Kse + A, G], -1), np.concatenate([B, Kbt + H], -1)], -2)
        vu = np.linalg.solve(M, np.concatenate([d, c], -1)[..., None])[..., 0]
        dp = np.einsum("kij,kj->ki", R, v)
        dR = (R @ uh).reshape(K, 9)
        return np.concatenate([dp, dR, vu], -1).T

    def bc(ya, yb):
        v, u = yb[12:15], yb[15:18]
        nsum = np.zeros(3)
        msum = np.zeros(3)
        for ti, (r, dr, _) in zip(tau, routing(bb.length)):
            pd = np.cross(u, r[0]) + dr[0] + v
            t = pd / np.linalg.norm(pd)
            nsum += ti * t
            msum += ti * np.cross(r[0], t)
        return np.concatenate(
            [ya[0:3], ya[3:12] - np.eye(3).ravel(), Kse @ (v - e3) + nsum, Kbt @ u + msum]
        )

    s = np.linspace(0, bb.length, guess_n)
    Y = np.zeros((18, guess_n))
    Y[2] = s
    Y[3:12] = np.eye(3).ravel()[:, None]
    Y[14] = 1.0
    sol = solve_bvp(rhs, bc, s, Y, tol=1e-8, max_nodes=20000)
    assert sol.status == 0, sol.message
    return sol


@pytest.mark.parametrize("tau", [[0.0, 0.0, 0.0, 4.0], [1.5, 0.0, 0.7, 3.0]])
def test_helical_routing_against_independent_bvp(paper, tau):
    sol = _rw_bvp(paper, np.array(tau))
    shape = with_step(paper, 0.2 / 160).solve_tensions(tau)
    ref = sol.sol(shape.s)
    np.testing.assert_allclose(shape.positions, ref[0:3].T, **TOL["bvp_positions"])
    np.testing.assert_allclose(shape.rotations.reshape(-1, 9), ref[3:12].T, **TOL["bvp_rotations"])


def _stiff(robot, factor=100.0):
    bb = robot.params.backbone
    return with_step(
        robot,
        bb.step,
        youngs_modulus=bb.youngs_modulus * factor,
        shear_modulus=bb.shear_modulus * factor,
    )


def test_gravity_small_deflection_cantilever(paper):
    """Horizontal cantilever under its own weight: tip deflection q L^4 / (8 E I)."""
    robot = (
        _stiff(paper)
        .with_base_pose(rpy=(0.0, np.pi / 2, 0.0))
        .with_gravity(True, (0.0, 0.0, -9.81))
    )
    shape = robot.solve_tensions([0.0, 0.0, 0.0, 0.0])
    q = robot._lam * 9.81
    bb = robot.params.backbone
    w = q * bb.length**4 / (8 * bb.kbt[0])
    np.testing.assert_allclose(-shape.tip[2], w, **TOL["small_deflection"])
    np.testing.assert_allclose(shape.tip[0], bb.length, **TOL["small_deflection_length"])


def test_gravity_along_backbone_compresses_linearly(paper):
    """Upright robot, gravity along -z: pure compression, tip z = L - q L^2 / (2 E A)."""
    robot = paper.with_gravity(True, (0.0, 0.0, -9.81))
    shape = robot.solve_tensions([0.0, 0.0, 0.0, 0.0])
    q = robot._lam * 9.81
    bb = robot.params.backbone
    np.testing.assert_allclose(
        shape.tip, [0, 0, bb.length - q * bb.length**2 / (2 * bb.kse[2])], **TOL["float64_abs"]
    )


def test_gravity_tension_shape_is_in_equilibrium(paper):
    """With gravity and tensions the shot solution meets the free-tip condition N(L) = M(L) = 0."""
    robot = paper.with_gravity(True, (9.81, 0.0, 0.0))
    Y = robot._shoot(np.array([1.0, 0.5, 0.0, 2.0]))
    assert np.abs(Y[-1, 12:15]).max() <= TOL["free_tip_force"]["atol"]
    assert np.abs(Y[-1, 15:18]).max() <= TOL["free_tip_moment"]["atol"]
    free = robot.with_gravity(False).solve_tensions([1.0, 0.5, 0.0, 2.0])
    assert np.linalg.norm(Y[-1, 0:3] - free.tip) > 1e-3  # gravity visibly moves the tip


def test_base_pose_transforms_rigidly(paper):
    tau = [2.0, 0.0, 1.0, 3.0]
    base = paper.solve_tensions(tau)
    pos = np.array([0.1, -0.2, 0.3])
    moved = paper.with_base_pose(pos, rpy=(0.3, -0.7, 1.1))
    R = moved.params.base.matrix
    shp = moved.solve_tensions(tau)
    np.testing.assert_allclose(shp.positions, base.positions @ R.T + pos, **TOL["float64_exact"])
    np.testing.assert_allclose(shp.rotations, R @ base.rotations, **TOL["float64_exact"])
