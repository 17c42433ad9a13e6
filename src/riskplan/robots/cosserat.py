"""Cosserat-rod statics of tendon-driven continuum robots with general tendon routing.

Implements Rucker & Webster, "Statics and dynamics of continuum robots with general tendon
routing and external loading", IEEE T-RO 27(6), 2011 (R&W below), in an equivalent
"resultant" form that needs no shooting when there are no external loads.

Model (body-frame strains ``v`` (shear/extension) and ``u`` (curvature/torsion), R&W eq. 2-4)::

    p' = R v,        R' = R [u]x,
    tendon i at body offset r_i(s) = rho_i(s) (cos theta_i(s), sin theta_i(s), 0),
    tendon tangent  w_i = v + u x r_i + r_i',  t_i = w_i / |w_i|       (R&W eq. 10)

Cut the robot *and its tendons* at ``s`` and take the distal part as one free body: the
tendon-disk contact forces are internal to it, the tendon tension enters only where the
tendons are cut. With ``N(s)``, ``M(s)`` the resultant force and moment (about ``p(s)``, world
frame) carried through the cross-section by rod and tendons together::

    N' = -f,   M' = -p' x N - l,   N(L) = F_tip, M(L) = L_tip                      (1)
    K_se (v - v*) + sum_i tau_i t_i         = R^T N                               (2)
    K_bt (u - u*) + sum_i tau_i r_i x t_i   = R^T M                               (3)

(2)-(3) are R&W's constitutive law ``n = R K_se (v - v*)``, ``m = R K_bt (u - u*)`` with the
tendon terms of their tip boundary condition (R&W eq. 17) carried to every ``s``; differentiating
them along ``s`` gives R&W's ODE (their eq. 19, the ``A, B, G, H`` matrices). The Jacobian of
(2)-(3) is exactly R&W's matrix ``[[K_se + A, G], [B, K_bt + H]]``. Without external loads
``N = M = 0`` everywhere, so the strains at each ``s`` follow from a local 6x6 Newton solve of
(2)-(3) and one RK4 pass integrates ``p, R`` (no shooting). With gravity or tip loads the base
values ``N(0), M(0)`` are shot (Newton, finite-difference Jacobian) so that (1) holds at the tip.

Tendon path length ``l_i = int_0^L |w_i| ds`` is integrated alongside (Simpson = RK4 for a
state-independent integrand). Reference state: straight, unstretched (``v* = e3``, ``u* = 0``).

Everything here is a pure array function (numba, ``cache=True``); ``robot.TendonRobot`` is the
validating facade. The per-node helpers that take array views are compiled with
``inline="always"``: passing views to separate functions cost more than their arithmetic.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# status codes returned by the kernels
OK = 0
LOCAL_FAIL = 1
OUTER_FAIL = 2

# step halvings of the displacement solve's line search (2**-30 ~ 1e-9 of a Newton step)
LINE_SEARCH_MAXIT = 30


@njit(cache=True)
def in_limits(values, low, high):
    """True if every entry of the C-contiguous ``values (..., m)`` is finite and within
    ``low[j] <= values[..., j] <= high[j]`` (a sub-microsecond check for the facade's fast path;
    the facade falls back to the numpy checks, which name the offending entry)."""
    m = low.shape[0]
    flat = values.reshape(-1)
    for k in range(flat.shape[0]):
        x = flat[k]
        if not (x >= low[k % m] and x <= high[k % m]):  # NaN fails both comparisons
            return False
    return True


@njit(cache=True)
def _polyval(c, s):
    out = 0.0
    for k in range(c.shape[0] - 1, -1, -1):
        out = out * s + c[k]
    return out


@njit(cache=True)
def _dpolyval(c, s):
    out = 0.0
    for k in range(c.shape[0] - 1, 0, -1):
        out = out * s + k * c[k]
    return out


@njit(cache=True)
def tendon_offsets(theta_c, radius_c, s, rt, drt):
    """Body-frame tendon offsets ``r_i(s)`` and derivatives ``r_i'(s)`` into ``rt, drt (m, 3)``.

    ``theta_c (m, Kt)``, ``radius_c (m, Kr)``: polynomial coefficients (ascending powers of s).
    """
    m = theta_c.shape[0]
    for i in range(m):
        th = _polyval(theta_c[i], s)
        dth = _dpolyval(theta_c[i], s)
        r = _polyval(radius_c[i], s)
        dr = _dpolyval(radius_c[i], s)
        c = math.cos(th)
        sn = math.sin(th)
        rt[i, 0] = r * c
        rt[i, 1] = r * sn
        rt[i, 2] = 0.0
        drt[i, 0] = dr * c - r * dth * sn
        drt[i, 1] = dr * sn + r * dth * c
        drt[i, 2] = 0.0


def tendon_offset_table(theta_c, radius_c, length, n_steps):
    """Offsets ``r_i``, ``r_i'``, ``r_i''`` at the ``2 n + 1`` RK4 nodes (steps and half steps):
    three arrays ``(2n+1, m, 3)``."""
    n_nodes = 2 * n_steps + 1
    m = theta_c.shape[0]
    rt_all = np.empty((n_nodes, m, 3))
    drt_all = np.empty((n_nodes, m, 3))
    ddrt_all = np.zeros((n_nodes, m, 3))
    h = length / n_steps
    P = np.polynomial.polynomial
    for j in range(n_nodes):
        tendon_offsets(theta_c, radius_c, j * 0.5 * h, rt_all[j], drt_all[j])
    s = np.arange(n_nodes) * 0.5 * h
    for i in range(m):
        th = P.polyval(s, theta_c[i])
        d1 = P.polyval(s, P.polyder(theta_c[i])) if theta_c.shape[1] > 1 else 0 * s
        d2 = P.polyval(s, P.polyder(theta_c[i], 2)) if theta_c.shape[1] > 2 else 0 * s
        rho = P.polyval(s, radius_c[i])
        r1 = P.polyval(s, P.polyder(radius_c[i])) if radius_c.shape[1] > 1 else 0 * s
        r2 = P.polyval(s, P.polyder(radius_c[i], 2)) if radius_c.shape[1] > 2 else 0 * s
        c, sn = np.cos(th), np.sin(th)
        ddrt_all[:, i, 0] = r2 * c - 2 * r1 * d1 * sn - rho * d2 * sn - rho * d1 * d1 * c
        ddrt_all[:, i, 1] = r2 * sn + 2 * r1 * d1 * c + rho * d2 * c - rho * d1 * d1 * sn
    return rt_all, drt_all, ddrt_all


@njit(cache=True)
def _gauss_solve(A, b, n, nrhs):
    """Solve ``A X = b`` in place (partial pivoting); ``A (n, n)``, ``b (n, nrhs)``. Returns False if singular."""
    for k in range(n):
        piv = k
        big = abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > big:
                big = abs(A[i, k])
                piv = i
        if big == 0.0:
            return False
        if piv != k:
            for j in range(n):
                tmp = A[k, j]
                A[k, j] = A[piv, j]
                A[piv, j] = tmp
            for j in range(nrhs):
                tmp = b[k, j]
                b[k, j] = b[piv, j]
                b[piv, j] = tmp
        inv = 1.0 / A[k, k]
        for i in range(k + 1, n):
            f = A[i, k] * inv
            if f != 0.0:
                for j in range(k + 1, n):
                    A[i, j] -= f * A[k, j]
                for j in range(nrhs):
                    b[i, j] -= f * b[k, j]
    for k in range(n - 1, -1, -1):
        for j in range(nrhs):
            acc = b[k, j]
            for i in range(k + 1, n):
                acc -= A[k, i] * b[i, j]
            b[k, j] = acc / A[k, k]
    return True


@njit(cache=True)
def _chol_factor6(J):
    """Cholesky factor (lower, in place) of a symmetric positive definite ``J (6, 6)``.

    The local Jacobian is SPD: ``K + sum_i T_i^T A_i T_i`` with ``T_i = [I, -[r_i]x]`` and
    ``A_i`` positive semidefinite. Returns False if a pivot is not positive."""
    for j in range(6):
        d = J[j, j]
        for k in range(j):
            d -= J[j, k] * J[j, k]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        J[j, j] = d
        inv = 1.0 / d
        for i in range(j + 1, 6):
            acc = J[i, j]
            for k in range(j):
                acc -= J[i, k] * J[j, k]
            J[i, j] = acc * inv
    return True


@njit(cache=True)
def _chol_solve6(L, b):
    """Solve ``L L^T x = b`` in place with the factor from :func:`_chol_factor6`."""
    for i in range(6):
        acc = b[i]
        for k in range(i):
            acc -= L[i, k] * b[k]
        b[i] = acc / L[i, i]
    for i in range(5, -1, -1):
        acc = b[i]
        for k in range(i + 1, 6):
            acc -= L[k, i] * b[k]
        b[i] = acc / L[i, i]


@njit(cache=True)
def local_residual(x, tau, rt, drt, nb, mb, kse, kbt, F):
    """Residual ``F (6,)`` of eqs. (2)-(3) at strains ``x = (v, u)``; returns ``max |F_a / K_aa|``
    (an estimate of the strain error, since the Jacobian is dominated by ``diag(K_se, K_bt)``)."""
    F[0] = kse[0] * x[0] - nb[0]
    F[1] = kse[1] * x[1] - nb[1]
    F[2] = kse[2] * (x[2] - 1.0) - nb[2]
    F[3] = kbt[0] * x[3] - mb[0]
    F[4] = kbt[1] * x[4] - mb[1]
    F[5] = kbt[2] * x[5] - mb[2]
    for i in range(tau.shape[0]):
        ti = tau[i]
        if ti == 0.0:
            continue
        r0 = rt[i, 0]
        r1 = rt[i, 1]
        r2 = rt[i, 2]
        w0 = x[0] + x[4] * r2 - x[5] * r1 + drt[i, 0]
        w1 = x[1] + x[5] * r0 - x[3] * r2 + drt[i, 1]
        w2 = x[2] + x[3] * r1 - x[4] * r0 + drt[i, 2]
        sc = ti / math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        F[0] += sc * w0
        F[1] += sc * w1
        F[2] += sc * w2
        F[3] += sc * (r1 * w2 - r2 * w1)
        F[4] += sc * (r2 * w0 - r0 * w2)
        F[5] += sc * (r0 * w1 - r1 * w0)
    e = 0.0
    for a in range(3):
        e = max(e, abs(F[a] / kse[a]), abs(F[3 + a] / kbt[a]))
    return e


@njit(cache=True)
def local_jacobian(x, tau, rt, drt, kse, kbt, J):
    """Jacobian ``J (6, 6)`` of eqs. (2)-(3): ``[[K_se + A, G], [B, K_bt + H]]`` with, per tendon,
    ``A_i = tau_i (I - t_i t_i^T)/|w_i|``, ``G_i = -A_i [r_i]x``, ``B_i = [r_i]x A_i``,
    ``H_i = -[r_i]x A_i [r_i]x`` (R&W eqs. 13-16)."""
    for a in range(6):
        for b in range(6):
            J[a, b] = 0.0
    J[0, 0] = kse[0]
    J[1, 1] = kse[1]
    J[2, 2] = kse[2]
    J[3, 3] = kbt[0]
    J[4, 4] = kbt[1]
    J[5, 5] = kbt[2]
    for i in range(tau.shape[0]):
        ti = tau[i]
        if ti == 0.0:
            continue
        r0 = rt[i, 0]
        r1 = rt[i, 1]
        r2 = rt[i, 2]
        w0 = x[0] + x[4] * r2 - x[5] * r1 + drt[i, 0]
        w1 = x[1] + x[5] * r0 - x[3] * r2 + drt[i, 1]
        w2 = x[2] + x[3] * r1 - x[4] * r0 + drt[i, 2]
        nw = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        t0 = w0 / nw
        t1 = w1 / nw
        t2 = w2 / nw
        sc = ti / nw
        a00 = sc * (1.0 - t0 * t0)
        a11 = sc * (1.0 - t1 * t1)
        a22 = sc * (1.0 - t2 * t2)
        a01 = -sc * t0 * t1
        a02 = -sc * t0 * t2
        a12 = -sc * t1 * t2
        # Bm = A [r]x, [r]x = [[0,-r2,r1],[r2,0,-r0],[-r1,r0,0]]
        b00 = a01 * r2 - a02 * r1
        b01 = -a00 * r2 + a02 * r0
        b02 = a00 * r1 - a01 * r0
        b10 = a11 * r2 - a12 * r1
        b11 = -a01 * r2 + a12 * r0
        b12 = a01 * r1 - a11 * r0
        b20 = a12 * r2 - a22 * r1
        b21 = -a02 * r2 + a22 * r0
        b22 = a02 * r1 - a12 * r0
        J[0, 0] += a00
        J[0, 1] += a01
        J[0, 2] += a02
        J[1, 0] += a01
        J[1, 1] += a11
        J[1, 2] += a12
        J[2, 0] += a02
        J[2, 1] += a12
        J[2, 2] += a22
        J[0, 3] -= b00
        J[0, 4] -= b01
        J[0, 5] -= b02
        J[1, 3] -= b10
        J[1, 4] -= b11
        J[1, 5] -= b12
        J[2, 3] -= b20
        J[2, 4] -= b21
        J[2, 5] -= b22
        J[3, 0] -= b00
        J[4, 0] -= b01
        J[5, 0] -= b02
        J[3, 1] -= b10
        J[4, 1] -= b11
        J[5, 1] -= b12
        J[3, 2] -= b20
        J[4, 2] -= b21
        J[5, 2] -= b22
        # H = -[r]x Bm
        J[3, 3] -= -r2 * b10 + r1 * b20
        J[3, 4] -= -r2 * b11 + r1 * b21
        J[3, 5] -= -r2 * b12 + r1 * b22
        J[4, 3] -= r2 * b00 - r0 * b20
        J[4, 4] -= r2 * b01 - r0 * b21
        J[4, 5] -= r2 * b02 - r0 * b22
        J[5, 3] -= -r1 * b00 + r0 * b10
        J[5, 4] -= -r1 * b01 + r0 * b11
        J[5, 5] -= -r1 * b02 + r0 * b12


@njit(cache=True)
def local_strains(x, tau, rt, drt, nb, mb, kse, kbt, tol, maxit, F, J, rhs):
    """Newton solve of eqs. (2)-(3) for ``x = (v, u)`` in place (``x`` is the warm start).

    Stops when ``max |F_a / K_aa| <= tol``. Returns the number of Newton steps, or -1.
    ``rhs`` is unused (kept for the signature); see :func:`local_strains_chord` for the
    variant that reuses factorisations.
    """
    for it in range(maxit):
        e = local_residual(x, tau, rt, drt, nb, mb, kse, kbt, F)
        if e <= tol:
            return it
        if not e == e:  # NaN
            return -1
        local_jacobian(x, tau, rt, drt, kse, kbt, J)
        if not _chol_factor6(J):
            return -1
        for a in range(6):
            F[a] = -F[a]
        _chol_solve6(J, F)
        for a in range(6):
            x[a] += F[a]
    return -1


@njit(cache=True, inline="always")
def local_strains_chord(x, tau, rt, drt, nb, mb, kse, kbt, tol, maxit, F, L, fac):
    """Like :func:`local_strains`, but reuses the Cholesky factor ``L`` of an earlier Jacobian
    (``fac[0] = 1`` when ``L`` holds one) while the residual falls by at least 4x per step,
    and refactors otherwise (a chord/Newton hybrid; the Jacobian changes little between
    neighbouring stations). Returns the number of steps, or -1.
    """
    e_prev = 1e300
    for it in range(maxit):
        e = local_residual(x, tau, rt, drt, nb, mb, kse, kbt, F)
        if e <= tol:
            return it
        if not e == e:
            return -1
        if fac[0] == 0 or e > 0.25 * e_prev:
            local_jacobian(x, tau, rt, drt, kse, kbt, L)
            if not _chol_factor6(L):
                fac[0] = 0
                return -1
            fac[0] = 1
        e_prev = e
        for a in range(6):
            F[a] = -F[a]
        _chol_solve6(L, F)
        for a in range(6):
            x[a] += F[a]
    return -1


@njit(cache=True, inline="always")
def _tendon_speeds(x, rt, drt, out):
    """``|w_i|`` for every tendon (path length per unit s)."""
    m = rt.shape[0]
    for i in range(m):
        r0 = rt[i, 0]
        r1 = rt[i, 1]
        r2 = rt[i, 2]
        w0 = x[0] + x[4] * r2 - x[5] * r1 + drt[i, 0]
        w1 = x[1] + x[5] * r0 - x[3] * r2 + drt[i, 1]
        w2 = x[2] + x[3] * r1 - x[4] * r0 + drt[i, 2]
        out[i] = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)


@njit(cache=True, inline="always")
def _rk4_pose_step(p, R, x0, xm, x1, h, pn, Rn):
    """Classical RK4 step of ``p' = R v``, ``R' = R [u]x`` with strains known at s, s+h/2, s+h.

    The ODE is linear in ``(p, R)`` row by row, so each row of ``R`` is stepped independently.
    """
    for a in range(3):
        q0 = R[a, 0]
        q1 = R[a, 1]
        q2 = R[a, 2]
        # k1 (row of R [u]x and row . v)
        k10 = q1 * x0[5] - q2 * x0[4]
        k11 = -q0 * x0[5] + q2 * x0[3]
        k12 = q0 * x0[4] - q1 * x0[3]
        kp1 = q0 * x0[0] + q1 * x0[1] + q2 * x0[2]
        s0 = q0 + 0.5 * h * k10
        s1 = q1 + 0.5 * h * k11
        s2 = q2 + 0.5 * h * k12
        k20 = s1 * xm[5] - s2 * xm[4]
        k21 = -s0 * xm[5] + s2 * xm[3]
        k22 = s0 * xm[4] - s1 * xm[3]
        kp2 = s0 * xm[0] + s1 * xm[1] + s2 * xm[2]
        s0 = q0 + 0.5 * h * k20
        s1 = q1 + 0.5 * h * k21
        s2 = q2 + 0.5 * h * k22
        k30 = s1 * xm[5] - s2 * xm[4]
        k31 = -s0 * xm[5] + s2 * xm[3]
        k32 = s0 * xm[4] - s1 * xm[3]
        kp3 = s0 * xm[0] + s1 * xm[1] + s2 * xm[2]
        s0 = q0 + h * k30
        s1 = q1 + h * k31
        s2 = q2 + h * k32
        k40 = s1 * x1[5] - s2 * x1[4]
        k41 = -s0 * x1[5] + s2 * x1[3]
        k42 = s0 * x1[4] - s1 * x1[3]
        kp4 = s0 * x1[0] + s1 * x1[1] + s2 * x1[2]
        c = h / 6.0
        Rn[a, 0] = q0 + c * (k10 + 2.0 * k20 + 2.0 * k30 + k40)
        Rn[a, 1] = q1 + c * (k11 + 2.0 * k21 + 2.0 * k31 + k41)
        Rn[a, 2] = q2 + c * (k12 + 2.0 * k22 + 2.0 * k32 + k42)
        pn[a] = p[a] + c * (kp1 + 2.0 * kp2 + 2.0 * kp3 + kp4)


@njit(cache=True)
def _deriv_pose(R, x, dR, dp):
    u0 = x[3]
    u1 = x[4]
    u2 = x[5]
    for a in range(3):
        dp[a] = R[a, 0] * x[0] + R[a, 1] * x[1] + R[a, 2] * x[2]
        # R [u]x, columns: R(u x e_j)
        dR[a, 0] = R[a, 1] * u2 - R[a, 2] * u1
        dR[a, 1] = -R[a, 0] * u2 + R[a, 2] * u0
        dR[a, 2] = R[a, 0] * u1 - R[a, 1] * u0


@njit(cache=True)
def _predict(xa, xb, xc, nhist, out):
    """Warm start for the next node: polynomial extrapolation from the last 1-3 node solutions."""
    for a in range(6):
        if nhist >= 3:
            out[a] = 3.0 * xa[a] - 3.0 * xb[a] + xc[a]
        elif nhist == 2:
            out[a] = 2.0 * xa[a] - xb[a]
        else:
            out[a] = xa[a]


@njit(cache=True)
def shape_free_exact_midpoints(tau, rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, p_out, R_out, x_out, lengths):
    """Reference variant of :func:`shape_free` that solves (2)-(3) at the half steps too.

    Shape under tendon tensions ``tau (m,)`` without external loads (no shooting).

    Outputs: ``p_out (n+1, 3)``, ``R_out (n+1, 3, 3)`` in the base frame, strains
    ``x_out (n+1, 6)`` and tendon path lengths ``lengths (m,)``. Returns a status code.
    """
    m = tau.shape[0]
    h = length / n_steps
    F = np.empty(6)
    J = np.empty((6, 6))
    fac = np.zeros(1, dtype=np.int64)
    zero = np.zeros(3)
    sp = np.empty(m)
    x0 = np.zeros(6)
    x0[2] = 1.0
    xm = np.empty(6)
    x1 = np.empty(6)
    rt = rt_all[0]
    drt = drt_all[0]
    if local_strains_chord(x0, tau, rt, drt, zero, zero, kse, kbt, tol, maxit, F, J, fac) < 0:
        return LOCAL_FAIL
    for a in range(3):
        p_out[0, a] = 0.0
        for b in range(3):
            R_out[0, a, b] = 1.0 if a == b else 0.0
    for a in range(6):
        x_out[0, a] = x0[a]
    for i in range(m):
        lengths[i] = 0.0
    _tendon_speeds(x0, rt, drt, sp)
    for i in range(m):
        lengths[i] += sp[i]
    xb = x0.copy()  # node solutions two and three half-steps back, for the predictor
    xc = x0.copy()
    nhist = 1
    for k in range(n_steps):
        s = k * h
        _predict(x0, xb, xc, nhist, xm)
        rt = rt_all[2 * k + 1]
        drt = drt_all[2 * k + 1]
        if local_strains_chord(xm, tau, rt, drt, zero, zero, kse, kbt, tol, maxit, F, J, fac) < 0:
            return LOCAL_FAIL
        _tendon_speeds(xm, rt, drt, sp)
        for i in range(m):
            lengths[i] += 4.0 * sp[i]
        nhist = min(nhist + 1, 3)
        _predict(xm, x0, xb, nhist, x1)
        rt = rt_all[2 * k + 2]
        drt = drt_all[2 * k + 2]
        if local_strains_chord(x1, tau, rt, drt, zero, zero, kse, kbt, tol, maxit, F, J, fac) < 0:
            return LOCAL_FAIL
        _tendon_speeds(x1, rt, drt, sp)
        w = 2.0 if k < n_steps - 1 else 1.0
        for i in range(m):
            lengths[i] += w * sp[i]
        _rk4_pose_step(p_out[k], R_out[k], x0, xm, x1, h, p_out[k + 1], R_out[k + 1])
        nhist = min(nhist + 1, 3)
        for a in range(6):
            x_out[k + 1, a] = x1[a]
            xc[a] = x0[a]
            xb[a] = xm[a]
            x0[a] = x1[a]
    for i in range(m):
        lengths[i] *= h / 6.0
    return OK


@njit(cache=True, inline="always")
def _strain_slope(x, tau, rt, drt, ddrt, L, out):
    """``x'(s) = -J^{-1} dF/ds`` at a solution ``x`` of (2)-(3) (implicit function theorem);
    ``L`` is the Cholesky factor of the Jacobian at ``x``. This is R&W's ODE for ``v', u'``."""
    for a in range(6):
        out[a] = 0.0
    for i in range(tau.shape[0]):
        ti = tau[i]
        if ti == 0.0:
            continue
        r0 = rt[i, 0]
        r1 = rt[i, 1]
        r2 = rt[i, 2]
        q0 = drt[i, 0]
        q1 = drt[i, 1]
        q2 = drt[i, 2]
        w0 = x[0] + x[4] * r2 - x[5] * r1 + q0
        w1 = x[1] + x[5] * r0 - x[3] * r2 + q1
        w2 = x[2] + x[3] * r1 - x[4] * r0 + q2
        nw = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        t0 = w0 / nw
        t1 = w1 / nw
        t2 = w2 / nw
        # dw/ds at fixed strains: u x r' + r''
        e0 = x[4] * q2 - x[5] * q1 + ddrt[i, 0]
        e1 = x[5] * q0 - x[3] * q2 + ddrt[i, 1]
        e2 = x[3] * q1 - x[4] * q0 + ddrt[i, 2]
        td = t0 * e0 + t1 * e1 + t2 * e2
        g0 = (e0 - t0 * td) / nw
        g1 = (e1 - t1 * td) / nw
        g2 = (e2 - t2 * td) / nw
        out[0] -= ti * g0
        out[1] -= ti * g1
        out[2] -= ti * g2
        out[3] -= ti * (q1 * t2 - q2 * t1 + r1 * g2 - r2 * g1)
        out[4] -= ti * (q2 * t0 - q0 * t2 + r2 * g0 - r0 * g2)
        out[5] -= ti * (q0 * t1 - q1 * t0 + r0 * g1 - r1 * g0)
    _chol_solve6(L, out)


@njit(cache=True)
def shape_free(tau, rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps, tol, maxit, p_out, R_out, x_out, lengths):
    """Shape under tendon tensions ``tau (m,)`` without external loads (no shooting).

    Strains solve (2)-(3) at the step nodes only; their slopes ``x'`` follow from the implicit
    function theorem (:func:`_strain_slope`), and the half-step strains RK4 needs come from the
    cubic Hermite interpolant ``x_m = (x_0 + x_1)/2 + h (x_0' - x_1')/8`` (error O(h^4), so the
    pass stays 4th order). The next node's Newton start is the Hermite extrapolation
    ``5 x_{k-1} + 2h x'_{k-1} - 4 x_k + 4h x'_k``; Newton reuses the fresh factor of the
    previous node (chord) and refactors only if it converges slowly.

    Outputs: ``p_out (n+1, 3)``, ``R_out (n+1, 3, 3)`` (base frame), strains ``x_out (n+1, 6)``,
    tendon path lengths ``lengths (m,)`` (Simpson). Returns a status code.
    """
    m = tau.shape[0]
    h = length / n_steps
    F = np.empty(6)
    L = np.empty((6, 6))
    fac = np.zeros(1, dtype=np.int64)
    zero = np.zeros(3)
    sp = np.empty(m)
    x0 = np.zeros(6)
    x0[2] = 1.0
    d0 = np.empty(6)
    xa = np.empty(6)  # previous node and its slope, for the predictor
    da = np.empty(6)
    x1 = np.empty(6)
    d1 = np.empty(6)
    xm = np.empty(6)
    if local_strains_chord(x0, tau, rt_all[0], drt_all[0], zero, zero, kse, kbt, tol, maxit, F, L, fac) < 0:
        return LOCAL_FAIL
    local_jacobian(x0, tau, rt_all[0], drt_all[0], kse, kbt, L)
    if not _chol_factor6(L):
        return LOCAL_FAIL
    fac[0] = 1
    for a in range(6):
        d0[a] = F[a]
    _strain_slope(x0, tau, rt_all[0], drt_all[0], ddrt_all[0], L, d0)
    for a in range(3):
        p_out[0, a] = 0.0
        for b in range(3):
            R_out[0, a, b] = 1.0 if a == b else 0.0
    for a in range(6):
        x_out[0, a] = x0[a]
    _tendon_speeds(x0, rt_all[0], drt_all[0], sp)
    for i in range(m):
        lengths[i] = sp[i]
    for k in range(n_steps):
        j1 = 2 * k + 2
        for a in range(6):
            if k == 0:
                x1[a] = x0[a] + h * d0[a]
            else:
                x1[a] = 5.0 * xa[a] + 2.0 * h * da[a] - 4.0 * x0[a] + 4.0 * h * d0[a]
        if local_strains_chord(x1, tau, rt_all[j1], drt_all[j1], zero, zero, kse, kbt, tol, maxit, F, L, fac) < 0:
            return LOCAL_FAIL
        local_jacobian(x1, tau, rt_all[j1], drt_all[j1], kse, kbt, L)
        if not _chol_factor6(L):
            return LOCAL_FAIL
        fac[0] = 1
        _strain_slope(x1, tau, rt_all[j1], drt_all[j1], ddrt_all[j1], L, d1)
        for a in range(6):
            xm[a] = 0.5 * (x0[a] + x1[a]) + 0.125 * h * (d0[a] - d1[a])
        _tendon_speeds(xm, rt_all[j1 - 1], drt_all[j1 - 1], sp)
        for i in range(m):
            lengths[i] += 4.0 * sp[i]
        _tendon_speeds(x1, rt_all[j1], drt_all[j1], sp)
        w = 2.0 if k < n_steps - 1 else 1.0
        for i in range(m):
            lengths[i] += w * sp[i]
        _rk4_pose_step(p_out[k], R_out[k], x0, xm, x1, h, p_out[k + 1], R_out[k + 1])
        for a in range(6):
            x_out[k + 1, a] = x1[a]
            xa[a] = x0[a]
            da[a] = d0[a]
            x0[a] = x1[a]
            d0[a] = d1[a]
    for i in range(m):
        lengths[i] *= h / 6.0
    return OK


@njit(cache=True)
def shape_free_batch(taus, rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps, tol, maxit, p_out, R_out, lengths_out, status):
    """Batched :func:`shape_free`: ``taus (B, m)`` -> ``p_out (B, n+1, 3)``, ``R_out (B, n+1, 3, 3)``."""
    B = taus.shape[0]
    x_out = np.empty((n_steps + 1, 6))
    for b in range(B):
        status[b] = shape_free(
            taus[b], rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps, tol, maxit, p_out[b], R_out[b], x_out, lengths_out[b]
        )


@njit(cache=True)
def lengths_and_jacobian(tau, rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, lengths, dl):
    """Tendon path lengths ``l (m,)`` and ``dl[i, j] = d l_i / d tau_j`` without external loads.

    Uses Simpson's rule on the RK4 nodes; the sensitivity of the local strains is
    ``dx/dtau_j = -J^{-1} [t_j; r_j x t_j]`` (implicit function theorem on eqs. (2)-(3)) and
    ``d|w_i|/dx = [t_i; r_i x t_i]``. Returns a status code.
    """
    m = tau.shape[0]
    h = length / n_steps
    n_nodes = 2 * n_steps + 1
    F = np.empty(6)
    J = np.empty((6, 6))
    fac = np.zeros(1, dtype=np.int64)
    col = np.empty(6)
    S = np.empty((6, m))
    G = np.empty((6, m))
    zero = np.zeros(3)
    x = np.zeros(6)
    x[2] = 1.0
    xprev = x.copy()
    for i in range(m):
        lengths[i] = 0.0
        for j in range(m):
            dl[i, j] = 0.0
    for node in range(n_nodes):
        rt = rt_all[node]
        drt = drt_all[node]
        if node >= 2:
            for a in range(6):
                tmp = x[a]
                x[a] = 2.0 * x[a] - xprev[a]
                xprev[a] = tmp
        else:
            for a in range(6):
                xprev[a] = x[a]
        if local_strains_chord(x, tau, rt, drt, zero, zero, kse, kbt, tol, maxit, F, J, fac) < 0:
            return LOCAL_FAIL
        local_jacobian(x, tau, rt, drt, kse, kbt, J)
        if not _chol_factor6(J):
            return LOCAL_FAIL
        fac[0] = 1
        if node == 0 or node == n_nodes - 1:
            wgt = h / 6.0
        elif node % 2 == 1:
            wgt = 4.0 * h / 6.0
        else:
            wgt = 2.0 * h / 6.0
        for i in range(m):
            r0 = rt[i, 0]
            r1 = rt[i, 1]
            r2 = rt[i, 2]
            w0 = x[0] + x[4] * r2 - x[5] * r1 + drt[i, 0]
            w1 = x[1] + x[5] * r0 - x[3] * r2 + drt[i, 1]
            w2 = x[2] + x[3] * r1 - x[4] * r0 + drt[i, 2]
            nw = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
            t0 = w0 / nw
            t1 = w1 / nw
            t2 = w2 / nw
            lengths[i] += wgt * nw
            G[0, i] = t0
            G[1, i] = t1
            G[2, i] = t2
            G[3, i] = r1 * t2 - r2 * t1
            G[4, i] = r2 * t0 - r0 * t2
            G[5, i] = r0 * t1 - r1 * t0
            for a in range(6):
                S[a, i] = -G[a, i]
        for j in range(m):
            for a in range(6):
                col[a] = S[a, j]
            _chol_solve6(J, col)
            for a in range(6):
                S[a, j] = col[a]
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for a in range(6):
                    acc += G[a, i] * S[a, j]
                dl[i, j] += wgt * acc
    return OK


@njit(cache=True, inline="always")
def _complementarity(d, kinv, l0, tau, lengths, dl, Jm, phi, fb, slack):
    """Newton system ``Jm step = phi`` of the complementarity problem at ``tau`` (see
    :func:`solve_displacement_tensions`) in length units, with ``a_i = tau_i * 1e-3`` (tensions in
    N compare with lengths in m at 1 mm/N) and ``b_i = g_i``: the min function
    ``r_i = min(a_i, b_i)`` (``fb = False``) or the Fischer-Burmeister function
    ``r_i = a_i + b_i - sqrt(a_i^2 + b_i^2)`` (``fb = True``, whose squared norm is smooth);
    ``phi = -r``, except that slack rows of the min function (``slack[i] = 1``) are written in
    tension units, ``step_i = -tau_i``. Returns ``(max |min(a_i, b_i)|, sum r_i^2)``."""
    m = d.shape[0]
    res = 0.0
    merit = 0.0
    for i in range(m):
        g = l0[i] - lengths[i] + tau[i] * kinv[i] - d[i]
        a = tau[i] * 1e-3
        res = max(res, abs(min(a, g)))
        if fb:
            nrm = math.sqrt(a * a + g * g)
            if nrm > 0.0:
                ca = 1.0 - a / nrm
                cb = 1.0 - g / nrm
            else:  # an element of the generalised Jacobian at the kink
                ca = 1.0 - 1.0 / math.sqrt(2.0)
                cb = ca
            r = a + g - nrm
            for j in range(m):
                Jm[i, j] = -cb * dl[i, j]
            Jm[i, i] += cb * kinv[i] + ca * 1e-3
            phi[i, 0] = -r
            slack[i] = 0
        elif tau[i] <= g:  # slack row kept in N (identity) so that a full step gives exactly 0
            for j in range(m):
                Jm[i, j] = 0.0
            Jm[i, i] = 1.0
            r = a
            phi[i, 0] = -tau[i]
            slack[i] = 1
        else:
            for j in range(m):
                Jm[i, j] = -dl[i, j]
            Jm[i, i] += kinv[i]
            r = g
            phi[i, 0] = -r
            slack[i] = 0
        merit += r * r
    return res, merit


@njit(cache=True, inline="always")
def _lm_system(Jm, phi, mu, A, b, m, slack):
    """``A = J^T J + mu I``, ``b = J^T phi`` (Levenberg-Marquardt normal equations) with the
    slack rows scaled to length units (1e-3 m/N) like the residual."""
    for i in range(m):
        acc = 0.0
        for k in range(m):
            w = 1e-6 if slack[k] else 1.0
            acc += w * Jm[k, i] * phi[k, 0]
        b[i, 0] = acc
        for j in range(m):
            acc = 0.0
            for k in range(m):
                w = 1e-6 if slack[k] else 1.0
                acc += w * Jm[k, i] * Jm[k, j]
            A[i, j] = acc
        A[i, i] += mu


@njit(cache=True, inline="always")
def _search_direction(Jm, phi, merit, slack, lm, A, step, m):
    """Newton step (``lm`` False) or Levenberg-Marquardt step into ``step``; False if singular."""
    if lm:
        _lm_system(Jm, phi, merit, A, step, m, slack)
    else:
        for i in range(m):
            step[i, 0] = phi[i, 0]
            for j in range(m):
                A[i, j] = Jm[i, j]
    return _gauss_solve(A, step, m, 1)


@njit(cache=True, inline="always")
def _line_search(d, kinv, l0, tau, step, merit, fb, rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, dtol, trial, lengths, dl, Jt, pt, slack_t):
    """Backtracking on the squared residual along ``step`` from ``tau`` (projected on tau >= 0):
    halves the step until it falls by the Armijo factor. Leaves the accepted point in ``trial``
    with its system in ``Jt, pt, slack_t``; returns ``(accepted, max residual, merit)``."""
    m = tau.shape[0]
    alpha = 1.0
    for _ls in range(LINE_SEARCH_MAXIT):
        for i in range(m):
            trial[i] = max(tau[i] + alpha * step[i, 0], 0.0)
        if lengths_and_jacobian(trial, rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, lengths, dl) == OK:
            res_t, merit_t = _complementarity(d, kinv, l0, trial, lengths, dl, Jt, pt, fb, slack_t)
            if merit_t <= (1.0 - 1e-4 * alpha) * merit or res_t <= dtol:
                return True, res_t, merit_t
        alpha *= 0.5
    return False, 0.0, 0.0


@njit(cache=True)
def solve_displacement_tensions(d, kinv, l0, tau0, rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, dtol, outer_maxit, tau, info):
    """Tensions for tendon displacements ``d (m,)`` with compliant tendons and slack (no loads).

    Complementarity (per tendon)::

        g_i(tau) = l0_i - l_i(tau) + tau_i * kinv_i - d_i,   tau_i >= 0, g_i >= 0, tau_i g_i = 0

    (pulling the actuator in by ``d_i`` shortens the tendon's rest length by ``d_i``; a taut
    tendon stretches by ``tau_i / k_i``). Semismooth Newton on ``min(tau, g) = 0`` with the
    analytic Jacobian of :func:`lengths_and_jacobian`, projected onto ``tau >= 0``, and a
    backtracking line search on the squared residual (steps are halved until it falls; the
    full step is taken whenever it does, so the local convergence stays quadratic). Needed for
    stiff problems such as inextensible antagonistic tendons, where full steps overshoot.
    ``tau0`` is the start. Writes ``tau``; ``info = [iterations, residual]``. Returns status.
    """
    m = d.shape[0]
    lengths = np.empty(m)
    dl = np.empty((m, m))
    Jm = np.empty((m, m))
    phi = np.empty((m, 1))
    trial = np.empty(m)
    Jt = np.empty((m, m))
    pt = np.empty((m, 1))
    Jc = np.empty((m, m))
    step = np.empty((m, 1))
    slack = np.zeros(m, dtype=np.int64)
    slack_t = np.zeros(m, dtype=np.int64)
    for i in range(m):
        tau[i] = tau0[i]
    info[0] = 0
    info[1] = 1e300
    fb = False
    st = lengths_and_jacobian(tau, rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, lengths, dl)
    if st != OK:
        return st
    res, merit = _complementarity(d, kinv, l0, tau, lengths, dl, Jm, phi, fb, slack)
    for it in range(outer_maxit):
        info[0] = it
        info[1] = res
        if res <= dtol:
            return OK
        # Newton step; if J is singular or the step finds no decrease, a Levenberg-Marquardt
        # step with mu = |r|^2 (Yamashita & Fukushima 2001: still quadratic near solutions that
        # are not isolated, e.g. tendons whose tension split is statically indeterminate)
        accepted = False
        for attempt in range(2):
            if _search_direction(Jm, phi, merit, slack, attempt == 1, Jc, step, m):
                accepted, res_t, merit_t = _line_search(
                    d, kinv, l0, tau, step, merit, fb, rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, dtol, trial, lengths, dl, Jt, pt, slack_t
                )
                if accepted:
                    break
        if not accepted:
            if fb:
                return OUTER_FAIL
            # stuck at a stationary point of the min-function merit that is not a solution
            # (it is not smooth): continue with the Fischer-Burmeister form, whose merit has
            # no such points when dg/dtau is positive semidefinite, as a compliance matrix is
            fb = True
            if lengths_and_jacobian(tau, rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, lengths, dl) != OK:
                return LOCAL_FAIL
            res, merit = _complementarity(d, kinv, l0, tau, lengths, dl, Jm, phi, fb, slack)
            continue
        for i in range(m):
            tau[i] = trial[i]
            slack[i] = slack_t[i]
            phi[i, 0] = pt[i, 0]
            for j in range(m):
                Jm[i, j] = Jt[i, j]
        res = res_t
        merit = merit_t
    info[0] = outer_maxit
    info[1] = res
    return OUTER_FAIL


@njit(cache=True)
def solve_displacement_batch(ds, kinv, l0, tau0s, rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, dtol, outer_maxit, taus, infos, status):
    """Batched :func:`solve_displacement_tensions` over ``ds (B, m)``; a configuration that fails
    from its start ``tau0s[b]`` is tried once more from the slack state (``infos`` of the last try)."""
    slack_start = np.zeros(ds.shape[1])
    for b in range(ds.shape[0]):
        st = solve_displacement_tensions(
            ds[b], kinv, l0, tau0s[b], rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, dtol, outer_maxit, taus[b], infos[b]
        )
        if st != OK:
            st = solve_displacement_tensions(
                ds[b], kinv, l0, slack_start, rt_all, drt_all, kse, kbt, length, n_steps, tol, maxit, dtol, outer_maxit, taus[b], infos[b]
            )
        status[b] = st


# ----------------------------------------------------------------------------- loaded case
@njit(cache=True)
def _deriv_loaded(y, node, tau, rt_all, drt_all, kse, kbt, f, x, tol, maxit, F, J, rhs, sp, dy):
    """Right-hand side of (1) with the strains from (2)-(3); ``y = (p, R (row-major), N, M, l)``.

    ``x`` is the warm start and receives the strains. Returns False if the local solve failed.
    """
    m = tau.shape[0]
    nb = np.empty(3)
    mb = np.empty(3)
    R = np.empty((3, 3))
    dR = np.empty((3, 3))
    dp = np.empty(3)
    for a in range(3):
        for b in range(3):
            R[a, b] = y[3 + 3 * a + b]
    N0 = y[12]
    N1 = y[13]
    N2 = y[14]
    for a in range(3):
        nb[a] = R[0, a] * N0 + R[1, a] * N1 + R[2, a] * N2
        mb[a] = R[0, a] * y[15] + R[1, a] * y[16] + R[2, a] * y[17]
    rt = rt_all[node]
    drt = drt_all[node]
    if local_strains(x, tau, rt, drt, nb, mb, kse, kbt, tol, maxit, F, J, rhs) < 0:
        return False
    _deriv_pose(R, x, dR, dp)
    for a in range(3):
        dy[a] = dp[a]
        for b in range(3):
            dy[3 + 3 * a + b] = dR[a, b]
        dy[12 + a] = -f[a]
    dy[15] = -(dp[1] * N2 - dp[2] * N1)
    dy[16] = -(dp[2] * N0 - dp[0] * N2)
    dy[17] = -(dp[0] * N1 - dp[1] * N0)
    _tendon_speeds(x, rt, drt, sp)
    for i in range(m):
        dy[18 + i] = sp[i]
    return True


@njit(cache=True)
def shape_loaded(tau, rt_all, drt_all, kse, kbt, length, n_steps, f, N0, M0, tol, maxit, Y):
    """Integrate (1)-(3) from base values ``N0, M0`` with distributed force ``f (3,)`` (base frame).

    ``Y (n+1, 18+m)`` receives the states ``(p, R row-major, N, M, l)``. Returns a status code.
    """
    m = tau.shape[0]
    ny = 18 + m
    h = length / n_steps
    F = np.empty(6)
    J = np.empty((6, 6))
    rhs = np.empty((6, 1))
    sp = np.empty(m)
    x = np.zeros(6)
    x[2] = 1.0
    k1 = np.empty(ny)
    k2 = np.empty(ny)
    k3 = np.empty(ny)
    k4 = np.empty(ny)
    ys = np.empty(ny)
    for a in range(ny):
        Y[0, a] = 0.0
    Y[0, 3] = 1.0
    Y[0, 7] = 1.0
    Y[0, 11] = 1.0
    for a in range(3):
        Y[0, 12 + a] = N0[a]
        Y[0, 15 + a] = M0[a]
    for k in range(n_steps):
        s = k * h
        y = Y[k]
        if not _deriv_loaded(y, 2 * k, tau, rt_all, drt_all, kse, kbt, f, x, tol, maxit, F, J, rhs, sp, k1):
            return LOCAL_FAIL
        for a in range(ny):
            ys[a] = y[a] + 0.5 * h * k1[a]
        if not _deriv_loaded(ys, 2 * k + 1, tau, rt_all, drt_all, kse, kbt, f, x, tol, maxit, F, J, rhs, sp, k2):
            return LOCAL_FAIL
        for a in range(ny):
            ys[a] = y[a] + 0.5 * h * k2[a]
        if not _deriv_loaded(ys, 2 * k + 1, tau, rt_all, drt_all, kse, kbt, f, x, tol, maxit, F, J, rhs, sp, k3):
            return LOCAL_FAIL
        for a in range(ny):
            ys[a] = y[a] + h * k3[a]
        if not _deriv_loaded(ys, 2 * k + 2, tau, rt_all, drt_all, kse, kbt, f, x, tol, maxit, F, J, rhs, sp, k4):
            return LOCAL_FAIL
        for a in range(ny):
            Y[k + 1, a] = y[a] + h / 6.0 * (k1[a] + 2.0 * k2[a] + 2.0 * k3[a] + k4[a])
    return OK


def strains_along(tau, theta_c, radius_c, kse, kbt, s, nb=None, mb=None, tol=1e-12, maxit=50):
    """Local strains ``(v, u)`` at arc lengths ``s (n,)`` (eqs. 2-3), ``-> (n, 6)``; for tests/diagnostics."""
    tau = np.ascontiguousarray(tau, dtype=np.float64)
    m = tau.shape[0]
    rt = np.empty((m, 3))
    drt = np.empty((m, 3))
    F = np.empty(6)
    J = np.empty((6, 6))
    rhs = np.empty((6, 1))
    out = np.empty((len(s), 6))
    x = np.array([0.0, 0, 1, 0, 0, 0])
    nb = np.zeros(3) if nb is None else np.asarray(nb, float)
    mb = np.zeros(3) if mb is None else np.asarray(mb, float)
    for k, sk in enumerate(s):
        tendon_offsets(theta_c, radius_c, float(sk), rt, drt)
        if local_strains(x, tau, rt, drt, nb, mb, kse, kbt, tol, maxit, F, J, rhs) < 0:
            raise RuntimeError("local strain solve failed")
        out[k] = x
    return out
