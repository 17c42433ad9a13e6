"""The local strain equations (2)-(3) of :mod:`riskplan.robots.cosserat` at one arc length:
residual, Jacobian (R&W eqs. 13-16), Newton and chord/Newton solves, the strain slope
``x' = -J^{-1} dF/ds`` (implicit function theorem = R&W's ODE for ``v', u'``) and the tendon
speeds ``|w_i|``. Strains ``x = (v, u) (6,)``; tendon offsets ``rt, drt (m, 3)`` at that node.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from riskplan.robots.linalg6 import chol_factor6, chol_solve6


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
        if not chol_factor6(J):
            return -1
        for a in range(6):
            F[a] = -F[a]
        chol_solve6(J, F)
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
            if not chol_factor6(L):
                fac[0] = 0
                return -1
            fac[0] = 1
        e_prev = e
        for a in range(6):
            F[a] = -F[a]
        chol_solve6(L, F)
        for a in range(6):
            x[a] += F[a]
    return -1


@njit(cache=True, inline="always")
def tendon_speeds(x, rt, drt, out):
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
def strain_slope(x, tau, rt, drt, ddrt, L, out):
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
    chol_solve6(L, out)
