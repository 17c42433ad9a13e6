"""The local strain equations (2)-(3) of :mod:`riskplan.robots.cosserat` at one arc length:
residual, Jacobian (R&W eqs. 13-16), Newton and chord/Newton solves, the strain slope
``x' = -J^{-1} dF/ds`` (implicit function theorem = R&W's ODE for ``v', u'``) and the tendon
speeds ``|w_i|``. Strains ``x = (v, u) (6,)``; tendon offsets ``rt, drt (m, 3)`` at that node.

:func:`local_strains` (Newton, a fresh factor every step: the loaded shooting path, whose
right-hand sides change between RK4 stages) and :func:`local_strains_chord` (reuses the last
factor while the residual falls fast: the unloaded pass, node after node) share the shape of
their loop on purpose: one function with a mode flag would add a branch and a factor-state
argument to the innermost solve of both hot paths for the sake of eight lines.
"""

from __future__ import annotations

import math

from numba import njit

from riskplan.robots.linalg6 import chol_factor6, chol_solve6

# ----------------------------------------------------------------------------------------
# Per-tendon terms, shared by the scalar kernels here and the lockstep kernel
# (``batch_kernel``); compiled inline, so each caller runs the same operations in the same
# order (the batch == scalar results are bit-identical). Strains ``x = (v, u)`` and offsets
# ``r, dr, ddr`` are anything indexable (array rows or tuples).


@njit(cache=True, inline="always")
def row3(a, i):
    """``(a[i, 0], a[i, 1], a[i, 2])``: a row as a tuple (no array view in the hot loops)."""
    return (a[i, 0], a[i, 1], a[i, 2])


@njit(cache=True, inline="always")
def tendon_tangent(x, r, dr):
    """``w = v + u x r + r'`` (R&W eq. 10), the unnormalised tendon tangent, as a 3-tuple."""
    return (
        x[0] + x[4] * r[2] - x[5] * r[1] + dr[0],
        x[1] + x[5] * r[0] - x[3] * r[2] + dr[1],
        x[2] + x[3] * r[1] - x[4] * r[0] + dr[2],
    )


@njit(cache=True, inline="always")
def unit_tangent(x, r, dr):
    """``(|w|, t0, t1, t2)``: the length of the tendon tangent ``w`` (:func:`tendon_tangent`)
    and the unit tangent ``t = w / |w|``."""
    w0, w1, w2 = tendon_tangent(x, r, dr)
    nw = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    return nw, w0 / nw, w1 / nw, w2 / nw


@njit(cache=True, inline="always")
def tendon_stiffness(sc, t0, t1, t2, r):
    """One tendon's Jacobian blocks (R&W eqs. 13-16) from ``sc = tau / |w|`` and the unit
    tangent ``t``: the symmetric ``A = sc (I - t t^T)`` as ``(a00, a11, a22, a01, a02, a12)``
    and ``Bm = A [r]x`` row by row (``b00 ... b22``); ``G = -Bm``, ``B = -Bm^T``,
    ``H = -[r]x Bm``."""
    r0 = r[0]
    r1 = r[1]
    r2 = r[2]
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
    return a00, a11, a22, a01, a02, a12, b00, b01, b02, b10, b11, b12, b20, b21, b22


@njit(cache=True, inline="always")
def tendon_slope_source(ti, nw, t0, t1, t2, x, r, dr, ddr):
    """One tendon's share of ``dF/ds`` at fixed strains (the right-hand side of the strain
    slope, :func:`strain_slope`): ``w' = u x r' + r''`` projected off the tangent, as the six
    terms the caller subtracts."""
    e0 = x[4] * dr[2] - x[5] * dr[1] + ddr[0]
    e1 = x[5] * dr[0] - x[3] * dr[2] + ddr[1]
    e2 = x[3] * dr[1] - x[4] * dr[0] + ddr[2]
    td = t0 * e0 + t1 * e1 + t2 * e2
    g0 = (e0 - t0 * td) / nw
    g1 = (e1 - t1 * td) / nw
    g2 = (e2 - t2 * td) / nw
    return (
        ti * g0,
        ti * g1,
        ti * g2,
        ti * (dr[1] * t2 - dr[2] * t1 + r[1] * g2 - r[2] * g1),
        ti * (dr[2] * t0 - dr[0] * t2 + r[2] * g0 - r[0] * g2),
        ti * (dr[0] * t1 - dr[1] * t0 + r[0] * g1 - r[1] * g0),
    )


@njit(cache=True, error_model="numpy")
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
        r0, r1, r2 = rt[i, 0], rt[i, 1], rt[i, 2]
        w0, w1, w2 = tendon_tangent(x, row3(rt, i), row3(drt, i))
        sc = ti / math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        F[0] += sc * w0
        F[1] += sc * w1
        F[2] += sc * w2
        F[3] += sc * (r1 * w2 - r2 * w1)
        F[4] += sc * (r2 * w0 - r0 * w2)
        F[5] += sc * (r0 * w1 - r1 * w0)
    # max(e, |F_a / K_aa|, ...) written out: numba's ``max`` of a tuple is an overload that a
    # first call compiles on its own; ``if v > e`` is the comparison it makes, in its order
    e = 0.0
    for a in range(3):
        v = abs(F[a] / kse[a])
        if v > e:
            e = v
        v = abs(F[3 + a] / kbt[a])
        if v > e:
            e = v
    return e


@njit(cache=True, error_model="numpy")
def local_jacobian(x, tau, rt, drt, kse, kbt, J):
    """Jacobian ``J (6, 6)`` of eqs. (2)-(3): ``[[K_se + A, G], [B, K_bt + H]]`` with, per tendon,
    ``A_i = tau_i (I - t_i t_i^T)/|w_i|``, ``G_i = -A_i [r_i]x``, ``B_i = [r_i]x A_i``,
    ``H_i = -[r_i]x A_i [r_i]x`` (R&W eqs. 13-16)."""
    for a in range(6):
        for b in range(6):
            J[a, b] = 0.0
    for a in range(3):
        J[a, a] = kse[a]
        J[3 + a, 3 + a] = kbt[a]
    for i in range(tau.shape[0]):
        ti = tau[i]
        if ti == 0.0:
            continue
        r0, r1, r2 = rt[i, 0], rt[i, 1], rt[i, 2]
        r = row3(rt, i)
        nw, t0, t1, t2 = unit_tangent(x, r, row3(drt, i))
        sc = ti / nw
        a00, a11, a22, a01, a02, a12, b00, b01, b02, b10, b11, b12, b20, b21, b22 = (
            tendon_stiffness(sc, t0, t1, t2, r)
        )
        # the blocks as loops over tuples (LLVM unrolls them; numba types a loop body once,
        # so a first call compiles this faster than the 45 statements written out)
        A = ((a00, a01, a02), (a01, a11, a12), (a02, a12, a22))
        Bm = ((b00, b01, b02), (b10, b11, b12), (b20, b21, b22))
        for p in range(3):
            for q in range(3):
                J[p, q] += A[p][q]
                J[p, 3 + q] -= Bm[p][q]  # G = -Bm
                J[3 + q, p] -= Bm[p][q]  # B = -Bm^T
        for q in range(3):  # H = -[r]x Bm
            J[3, 3 + q] -= -r2 * Bm[1][q] + r1 * Bm[2][q]
            J[4, 3 + q] -= r2 * Bm[0][q] - r0 * Bm[2][q]
            J[5, 3 + q] -= -r1 * Bm[0][q] + r0 * Bm[1][q]


@njit(cache=True, inline="always")
def _newton_update(x, F, L):
    """``x += -J^{-1} F`` with the Cholesky factor ``L`` of ``J`` (``F`` is overwritten)."""
    for a in range(6):
        F[a] = -F[a]
    chol_solve6(L, F)
    for a in range(6):
        x[a] += F[a]


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
        _newton_update(x, F, J)
    return -1


@njit(cache=True, inline="always")
def local_strains_chord(x, tau, rt, drt, nb, mb, kse, kbt, tol, maxit, F, L, fac):
    """Like :func:`local_strains`, but reuses the Cholesky factor ``L`` of an earlier Jacobian
    (``fac[0] = 1.0`` when ``L`` holds one) while the residual falls by at least 4x per step,
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
        if fac[0] == 0.0 or e > 0.25 * e_prev:
            local_jacobian(x, tau, rt, drt, kse, kbt, L)
            if not chol_factor6(L):
                fac[0] = 0.0
                return -1
            fac[0] = 1.0
        e_prev = e
        _newton_update(x, F, L)
    return -1


@njit(cache=True, inline="always")
def tendon_speeds(x, rt, drt, out):
    """``|w_i|`` for every tendon (path length per unit s)."""
    m = rt.shape[0]
    for i in range(m):
        w0, w1, w2 = tendon_tangent(x, row3(rt, i), row3(drt, i))
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
        r = row3(rt, i)
        dr = row3(drt, i)
        nw, t0, t1, t2 = unit_tangent(x, r, dr)
        c0, c1, c2, c3, c4, c5 = tendon_slope_source(ti, nw, t0, t1, t2, x, r, dr, row3(ddrt, i))
        out[0] -= c0
        out[1] -= c1
        out[2] -= c2
        out[3] -= c3
        out[4] -= c4
        out[5] -= c5
    chol_solve6(L, out)
