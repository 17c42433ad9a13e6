"""Batched tension-input shape solve: the algorithm of :func:`riskplan.robots.cosserat.shape_free`,
vectorised across configurations.

:func:`cosserat.shape_free` solves, for one configuration, the local strain equations (2)-(3)
of that module (R&W eqs. 13-17 in resultant form, no external load) at the ``n + 1`` step
nodes by a chord/Newton hybrid with a Cholesky factor of the SPD Jacobian, gets the strain
slopes ``x' = -J^{-1} dF/ds`` (implicit function theorem = R&W's ODE for ``v', u'``), the
half-step strains from the cubic Hermite interpolant and integrates ``p, R`` with one RK4 pass.

Here the same operations run in lockstep on a chunk of ``CHUNK`` configurations kept in a
structure-of-arrays work array ``W (rows, CHUNK)`` (configuration index innermost and
contiguous), so every stage is one loop over the chunk that LLVM turns into SIMD code. The
per-configuration control flow of the scalar kernel is kept exactly, as masks: a
configuration stops its chord iterations when its own strain error ``max |F_a / K_aa|`` drops
to ``tol``, refactors its Jacobian only when its own residual fell by less than 4x (a
factorisation is computed for the chunk when any member needs one and kept only by those),
and configurations that fail (non-positive pivot, NaN, ``maxit`` steps) are flagged and
re-solved by the scalar kernel. Every operation on one configuration is the scalar kernel's
operation in the same order, so results agree with it to rounding (in practice bit for bit).

Tendon path lengths are not computed (the shape needs none).
"""

from __future__ import annotations

import math

import numpy as np
from numba import get_num_threads, njit, prange

from riskplan.errors import ConvergenceError, InvalidInputError
from riskplan.robots import cosserat

__all__ = ["CHUNK", "solve_tensions_batch"]

CHUNK = 32  # configurations per chunk (the work array, 107 x 32 doubles, stays in L1)

# rows of the work array W (NROWS, CHUNK)
X0 = 0  # strains (v, u) at the current node
D0 = 6  # their slopes
XA = 12  # previous node and slope, for the predictor
DA = 18
X1 = 24  # next node
D1 = 30
XM = 36  # Hermite midpoint
FR = 42  # residual of (2)-(3)
JL = 48  # Jacobian, packed lower triangle (21), factored in place
LL = 69  # Cholesky factor in use (21)
PR = 90  # position (3)
RR = 93  # rotation, row-major (9)
ER = 102  # strain error of the last residual
EP = 103  # previous strain error (chord/refactor decision)
ACT = 104  # 1.0 while the chord iteration runs
NEED = 105  # 1.0 when a configuration refactors this iteration
FAIL = 106  # 1.0 when a configuration failed (scalar fallback)
NROWS = 107


@njit(cache=True, error_model="numpy", inline="always")
def _residual(W, T, rt_all, drt_all, node, kse, kbt, XR):
    """Residual of eqs. (2)-(3) at strains ``W[XR:XR+6]`` into ``W[FR:FR+6]`` (``cosserat.local_residual``)."""
    m = T.shape[0]
    k0 = kse[0]
    k1 = kse[1]
    k2 = kse[2]
    g0 = kbt[0]
    g1 = kbt[1]
    g2 = kbt[2]
    for c in range(CHUNK):
        W[FR + 0, c] = k0 * W[XR + 0, c]
        W[FR + 1, c] = k1 * W[XR + 1, c]
        W[FR + 2, c] = k2 * (W[XR + 2, c] - 1.0)
        W[FR + 3, c] = g0 * W[XR + 3, c]
        W[FR + 4, c] = g1 * W[XR + 4, c]
        W[FR + 5, c] = g2 * W[XR + 5, c]
    for i in range(m):
        r0 = rt_all[node, i, 0]
        r1 = rt_all[node, i, 1]
        r2 = rt_all[node, i, 2]
        q0 = drt_all[node, i, 0]
        q1 = drt_all[node, i, 1]
        q2 = drt_all[node, i, 2]
        for c in range(CHUNK):
            ti = T[i, c]
            x0 = W[XR + 0, c]
            x1 = W[XR + 1, c]
            x2 = W[XR + 2, c]
            x3 = W[XR + 3, c]
            x4 = W[XR + 4, c]
            x5 = W[XR + 5, c]
            w0 = x0 + x4 * r2 - x5 * r1 + q0
            w1 = x1 + x5 * r0 - x3 * r2 + q1
            w2 = x2 + x3 * r1 - x4 * r0 + q2
            sc = ti / math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
            W[FR + 0, c] += sc * w0
            W[FR + 1, c] += sc * w1
            W[FR + 2, c] += sc * w2
            W[FR + 3, c] += sc * (r1 * w2 - r2 * w1)
            W[FR + 4, c] += sc * (r2 * w0 - r0 * w2)
            W[FR + 5, c] += sc * (r0 * w1 - r1 * w0)


@njit(cache=True, error_model="numpy", inline="always")
def _jac_chol(W, T, rt_all, drt_all, node, kse, kbt, XR, always):
    """Jacobian of (2)-(3) at ``W[XR:XR+6]`` (``cosserat.local_jacobian``, lower triangle) and its
    Cholesky factor; stored into ``W[LL:]`` for every configuration (``always``) or for those
    with ``W[NEED] = 1``. A non-positive pivot in a stored factor marks the configuration failed."""
    m = T.shape[0]
    for c in range(CHUNK):
        for a in range(21):
            W[JL + a, c] = 0.0
        W[JL + 0, c] = kse[0]
        W[JL + 2, c] = kse[1]
        W[JL + 5, c] = kse[2]
        W[JL + 9, c] = kbt[0]
        W[JL + 14, c] = kbt[1]
        W[JL + 20, c] = kbt[2]
    for i in range(m):
        r0 = rt_all[node, i, 0]
        r1 = rt_all[node, i, 1]
        r2 = rt_all[node, i, 2]
        q0 = drt_all[node, i, 0]
        q1 = drt_all[node, i, 1]
        q2 = drt_all[node, i, 2]
        for c in range(CHUNK):
            ti = T[i, c]
            x0 = W[XR + 0, c]
            x1 = W[XR + 1, c]
            x2 = W[XR + 2, c]
            x3 = W[XR + 3, c]
            x4 = W[XR + 4, c]
            x5 = W[XR + 5, c]
            w0 = x0 + x4 * r2 - x5 * r1 + q0
            w1 = x1 + x5 * r0 - x3 * r2 + q1
            w2 = x2 + x3 * r1 - x4 * r0 + q2
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
            b00 = a01 * r2 - a02 * r1
            b01 = -a00 * r2 + a02 * r0
            b02 = a00 * r1 - a01 * r0
            b10 = a11 * r2 - a12 * r1
            b11 = -a01 * r2 + a12 * r0
            b12 = a01 * r1 - a11 * r0
            b20 = a12 * r2 - a22 * r1
            b21 = -a02 * r2 + a22 * r0
            b22 = a02 * r1 - a12 * r0
            W[JL + 0, c] += a00
            W[JL + 1, c] += a01
            W[JL + 2, c] += a11
            W[JL + 3, c] += a02
            W[JL + 4, c] += a12
            W[JL + 5, c] += a22
            W[JL + 6, c] -= b00
            W[JL + 10, c] -= b01
            W[JL + 15, c] -= b02
            W[JL + 7, c] -= b10
            W[JL + 11, c] -= b11
            W[JL + 16, c] -= b12
            W[JL + 8, c] -= b20
            W[JL + 12, c] -= b21
            W[JL + 17, c] -= b22
            W[JL + 9, c] -= -r2 * b10 + r1 * b20
            W[JL + 13, c] -= r2 * b00 - r0 * b20
            W[JL + 14, c] -= r2 * b01 - r0 * b21
            W[JL + 18, c] -= -r1 * b00 + r0 * b10
            W[JL + 19, c] -= -r1 * b01 + r0 * b11
            W[JL + 20, c] -= -r1 * b02 + r0 * b12
    for c in range(CHUNK):
        j00 = W[JL + 0, c]
        j10 = W[JL + 1, c]
        j11 = W[JL + 2, c]
        j20 = W[JL + 3, c]
        j21 = W[JL + 4, c]
        j22 = W[JL + 5, c]
        j30 = W[JL + 6, c]
        j31 = W[JL + 7, c]
        j32 = W[JL + 8, c]
        j33 = W[JL + 9, c]
        j40 = W[JL + 10, c]
        j41 = W[JL + 11, c]
        j42 = W[JL + 12, c]
        j43 = W[JL + 13, c]
        j44 = W[JL + 14, c]
        j50 = W[JL + 15, c]
        j51 = W[JL + 16, c]
        j52 = W[JL + 17, c]
        j53 = W[JL + 18, c]
        j54 = W[JL + 19, c]
        j55 = W[JL + 20, c]
        bad = False
        d = j00
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j00 = d
        inv = 1.0 / d
        acc = j10
        j10 = acc * inv
        acc = j20
        j20 = acc * inv
        acc = j30
        j30 = acc * inv
        acc = j40
        j40 = acc * inv
        acc = j50
        j50 = acc * inv
        d = j11
        d -= j10 * j10
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j11 = d
        inv = 1.0 / d
        acc = j21
        acc -= j20 * j10
        j21 = acc * inv
        acc = j31
        acc -= j30 * j10
        j31 = acc * inv
        acc = j41
        acc -= j40 * j10
        j41 = acc * inv
        acc = j51
        acc -= j50 * j10
        j51 = acc * inv
        d = j22
        d -= j20 * j20
        d -= j21 * j21
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j22 = d
        inv = 1.0 / d
        acc = j32
        acc -= j30 * j20
        acc -= j31 * j21
        j32 = acc * inv
        acc = j42
        acc -= j40 * j20
        acc -= j41 * j21
        j42 = acc * inv
        acc = j52
        acc -= j50 * j20
        acc -= j51 * j21
        j52 = acc * inv
        d = j33
        d -= j30 * j30
        d -= j31 * j31
        d -= j32 * j32
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j33 = d
        inv = 1.0 / d
        acc = j43
        acc -= j40 * j30
        acc -= j41 * j31
        acc -= j42 * j32
        j43 = acc * inv
        acc = j53
        acc -= j50 * j30
        acc -= j51 * j31
        acc -= j52 * j32
        j53 = acc * inv
        d = j44
        d -= j40 * j40
        d -= j41 * j41
        d -= j42 * j42
        d -= j43 * j43
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j44 = d
        inv = 1.0 / d
        acc = j54
        acc -= j50 * j40
        acc -= j51 * j41
        acc -= j52 * j42
        acc -= j53 * j43
        j54 = acc * inv
        d = j55
        d -= j50 * j50
        d -= j51 * j51
        d -= j52 * j52
        d -= j53 * j53
        d -= j54 * j54
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j55 = d
        inv = 1.0 / d
        upd = always or W[NEED, c] != 0.0
        W[LL + 0, c] = j00 if upd else W[LL + 0, c]
        W[LL + 1, c] = j10 if upd else W[LL + 1, c]
        W[LL + 2, c] = j11 if upd else W[LL + 2, c]
        W[LL + 3, c] = j20 if upd else W[LL + 3, c]
        W[LL + 4, c] = j21 if upd else W[LL + 4, c]
        W[LL + 5, c] = j22 if upd else W[LL + 5, c]
        W[LL + 6, c] = j30 if upd else W[LL + 6, c]
        W[LL + 7, c] = j31 if upd else W[LL + 7, c]
        W[LL + 8, c] = j32 if upd else W[LL + 8, c]
        W[LL + 9, c] = j33 if upd else W[LL + 9, c]
        W[LL + 10, c] = j40 if upd else W[LL + 10, c]
        W[LL + 11, c] = j41 if upd else W[LL + 11, c]
        W[LL + 12, c] = j42 if upd else W[LL + 12, c]
        W[LL + 13, c] = j43 if upd else W[LL + 13, c]
        W[LL + 14, c] = j44 if upd else W[LL + 14, c]
        W[LL + 15, c] = j50 if upd else W[LL + 15, c]
        W[LL + 16, c] = j51 if upd else W[LL + 16, c]
        W[LL + 17, c] = j52 if upd else W[LL + 17, c]
        W[LL + 18, c] = j53 if upd else W[LL + 18, c]
        W[LL + 19, c] = j54 if upd else W[LL + 19, c]
        W[LL + 20, c] = j55 if upd else W[LL + 20, c]
        fl = bad and upd
        W[FAIL, c] = 1.0 if fl else W[FAIL, c]
        W[ACT, c] = 0.0 if fl else W[ACT, c]


@njit(cache=True, error_model="numpy", inline="always")
def _jac_chol_slope(W, T, rt_all, drt_all, ddrt_all, node, kse, kbt, XR, DR):
    """:func:`_jac_chol` (``always``) and the strain slope (``cosserat._strain_slope``) fused: one pass over the tendons at the
    converged strains ``W[XR:]`` builds the Jacobian and the slope's right-hand side; the factor
    goes to ``W[LL:]`` and the slope ``x' = -J^{-1} dF/ds`` to ``W[DR:]``. Same operations as
    ``cosserat.local_jacobian``, ``_chol_factor6`` and ``_strain_slope``."""
    m = T.shape[0]
    for c in range(CHUNK):
        for a in range(21):
            W[JL + a, c] = 0.0
        W[JL + 0, c] = kse[0]
        W[JL + 2, c] = kse[1]
        W[JL + 5, c] = kse[2]
        W[JL + 9, c] = kbt[0]
        W[JL + 14, c] = kbt[1]
        W[JL + 20, c] = kbt[2]
        for a in range(6):
            W[DR + a, c] = 0.0
    for i in range(m):
        r0 = rt_all[node, i, 0]
        r1 = rt_all[node, i, 1]
        r2 = rt_all[node, i, 2]
        q0 = drt_all[node, i, 0]
        q1 = drt_all[node, i, 1]
        q2 = drt_all[node, i, 2]
        dd0 = ddrt_all[node, i, 0]
        dd1 = ddrt_all[node, i, 1]
        dd2 = ddrt_all[node, i, 2]
        for c in range(CHUNK):
            ti = T[i, c]
            x0 = W[XR + 0, c]
            x1 = W[XR + 1, c]
            x2 = W[XR + 2, c]
            x3 = W[XR + 3, c]
            x4 = W[XR + 4, c]
            x5 = W[XR + 5, c]
            w0 = x0 + x4 * r2 - x5 * r1 + q0
            w1 = x1 + x5 * r0 - x3 * r2 + q1
            w2 = x2 + x3 * r1 - x4 * r0 + q2
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
            b00 = a01 * r2 - a02 * r1
            b01 = -a00 * r2 + a02 * r0
            b02 = a00 * r1 - a01 * r0
            b10 = a11 * r2 - a12 * r1
            b11 = -a01 * r2 + a12 * r0
            b12 = a01 * r1 - a11 * r0
            b20 = a12 * r2 - a22 * r1
            b21 = -a02 * r2 + a22 * r0
            b22 = a02 * r1 - a12 * r0
            W[JL + 0, c] += a00
            W[JL + 1, c] += a01
            W[JL + 2, c] += a11
            W[JL + 3, c] += a02
            W[JL + 4, c] += a12
            W[JL + 5, c] += a22
            W[JL + 6, c] -= b00
            W[JL + 10, c] -= b01
            W[JL + 15, c] -= b02
            W[JL + 7, c] -= b10
            W[JL + 11, c] -= b11
            W[JL + 16, c] -= b12
            W[JL + 8, c] -= b20
            W[JL + 12, c] -= b21
            W[JL + 17, c] -= b22
            W[JL + 9, c] -= -r2 * b10 + r1 * b20
            W[JL + 13, c] -= r2 * b00 - r0 * b20
            W[JL + 14, c] -= r2 * b01 - r0 * b21
            W[JL + 18, c] -= -r1 * b00 + r0 * b10
            W[JL + 19, c] -= -r1 * b01 + r0 * b11
            W[JL + 20, c] -= -r1 * b02 + r0 * b12
            e0 = x4 * q2 - x5 * q1 + dd0
            e1 = x5 * q0 - x3 * q2 + dd1
            e2 = x3 * q1 - x4 * q0 + dd2
            td = t0 * e0 + t1 * e1 + t2 * e2
            h0 = (e0 - t0 * td) / nw
            h1 = (e1 - t1 * td) / nw
            h2 = (e2 - t2 * td) / nw
            W[DR + 0, c] -= ti * h0
            W[DR + 1, c] -= ti * h1
            W[DR + 2, c] -= ti * h2
            W[DR + 3, c] -= ti * (q1 * t2 - q2 * t1 + r1 * h2 - r2 * h1)
            W[DR + 4, c] -= ti * (q2 * t0 - q0 * t2 + r2 * h0 - r0 * h2)
            W[DR + 5, c] -= ti * (q0 * t1 - q1 * t0 + r0 * h1 - r1 * h0)
    for c in range(CHUNK):
        j00 = W[JL + 0, c]
        j10 = W[JL + 1, c]
        j11 = W[JL + 2, c]
        j20 = W[JL + 3, c]
        j21 = W[JL + 4, c]
        j22 = W[JL + 5, c]
        j30 = W[JL + 6, c]
        j31 = W[JL + 7, c]
        j32 = W[JL + 8, c]
        j33 = W[JL + 9, c]
        j40 = W[JL + 10, c]
        j41 = W[JL + 11, c]
        j42 = W[JL + 12, c]
        j43 = W[JL + 13, c]
        j44 = W[JL + 14, c]
        j50 = W[JL + 15, c]
        j51 = W[JL + 16, c]
        j52 = W[JL + 17, c]
        j53 = W[JL + 18, c]
        j54 = W[JL + 19, c]
        j55 = W[JL + 20, c]
        bad = False
        d = j00
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j00 = d
        inv = 1.0 / d
        acc = j10
        j10 = acc * inv
        acc = j20
        j20 = acc * inv
        acc = j30
        j30 = acc * inv
        acc = j40
        j40 = acc * inv
        acc = j50
        j50 = acc * inv
        d = j11
        d -= j10 * j10
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j11 = d
        inv = 1.0 / d
        acc = j21
        acc -= j20 * j10
        j21 = acc * inv
        acc = j31
        acc -= j30 * j10
        j31 = acc * inv
        acc = j41
        acc -= j40 * j10
        j41 = acc * inv
        acc = j51
        acc -= j50 * j10
        j51 = acc * inv
        d = j22
        d -= j20 * j20
        d -= j21 * j21
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j22 = d
        inv = 1.0 / d
        acc = j32
        acc -= j30 * j20
        acc -= j31 * j21
        j32 = acc * inv
        acc = j42
        acc -= j40 * j20
        acc -= j41 * j21
        j42 = acc * inv
        acc = j52
        acc -= j50 * j20
        acc -= j51 * j21
        j52 = acc * inv
        d = j33
        d -= j30 * j30
        d -= j31 * j31
        d -= j32 * j32
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j33 = d
        inv = 1.0 / d
        acc = j43
        acc -= j40 * j30
        acc -= j41 * j31
        acc -= j42 * j32
        j43 = acc * inv
        acc = j53
        acc -= j50 * j30
        acc -= j51 * j31
        acc -= j52 * j32
        j53 = acc * inv
        d = j44
        d -= j40 * j40
        d -= j41 * j41
        d -= j42 * j42
        d -= j43 * j43
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j44 = d
        inv = 1.0 / d
        acc = j54
        acc -= j50 * j40
        acc -= j51 * j41
        acc -= j52 * j42
        acc -= j53 * j43
        j54 = acc * inv
        d = j55
        d -= j50 * j50
        d -= j51 * j51
        d -= j52 * j52
        d -= j53 * j53
        d -= j54 * j54
        bad = bad | (not d > 0.0)
        d = math.sqrt(d)
        j55 = d
        inv = 1.0 / d
        W[LL + 0, c] = j00
        W[LL + 1, c] = j10
        W[LL + 2, c] = j11
        W[LL + 3, c] = j20
        W[LL + 4, c] = j21
        W[LL + 5, c] = j22
        W[LL + 6, c] = j30
        W[LL + 7, c] = j31
        W[LL + 8, c] = j32
        W[LL + 9, c] = j33
        W[LL + 10, c] = j40
        W[LL + 11, c] = j41
        W[LL + 12, c] = j42
        W[LL + 13, c] = j43
        W[LL + 14, c] = j44
        W[LL + 15, c] = j50
        W[LL + 16, c] = j51
        W[LL + 17, c] = j52
        W[LL + 18, c] = j53
        W[LL + 19, c] = j54
        W[LL + 20, c] = j55
        W[FAIL, c] = 1.0 if bad else W[FAIL, c]
        l00 = j00
        l10 = j10
        l11 = j11
        l20 = j20
        l21 = j21
        l22 = j22
        l30 = j30
        l31 = j31
        l32 = j32
        l33 = j33
        l40 = j40
        l41 = j41
        l42 = j42
        l43 = j43
        l44 = j44
        l50 = j50
        l51 = j51
        l52 = j52
        l53 = j53
        l54 = j54
        l55 = j55
        b0 = W[DR + 0, c]
        b1 = W[DR + 1, c]
        b2 = W[DR + 2, c]
        b3 = W[DR + 3, c]
        b4 = W[DR + 4, c]
        b5 = W[DR + 5, c]
        acc = b0
        b0 = acc / l00
        acc = b1
        acc -= l10 * b0
        b1 = acc / l11
        acc = b2
        acc -= l20 * b0
        acc -= l21 * b1
        b2 = acc / l22
        acc = b3
        acc -= l30 * b0
        acc -= l31 * b1
        acc -= l32 * b2
        b3 = acc / l33
        acc = b4
        acc -= l40 * b0
        acc -= l41 * b1
        acc -= l42 * b2
        acc -= l43 * b3
        b4 = acc / l44
        acc = b5
        acc -= l50 * b0
        acc -= l51 * b1
        acc -= l52 * b2
        acc -= l53 * b3
        acc -= l54 * b4
        b5 = acc / l55
        acc = b5
        b5 = acc / l55
        acc = b4
        acc -= l54 * b5
        b4 = acc / l44
        acc = b3
        acc -= l43 * b4
        acc -= l53 * b5
        b3 = acc / l33
        acc = b2
        acc -= l32 * b3
        acc -= l42 * b4
        acc -= l52 * b5
        b2 = acc / l22
        acc = b1
        acc -= l21 * b2
        acc -= l31 * b3
        acc -= l41 * b4
        acc -= l51 * b5
        b1 = acc / l11
        acc = b0
        acc -= l10 * b1
        acc -= l20 * b2
        acc -= l30 * b3
        acc -= l40 * b4
        acc -= l50 * b5
        b0 = acc / l00
        W[DR + 0, c] = b0
        W[DR + 1, c] = b1
        W[DR + 2, c] = b2
        W[DR + 3, c] = b3
        W[DR + 4, c] = b4
        W[DR + 5, c] = b5


@njit(cache=True, error_model="numpy", inline="always")
def _chord(W, T, rt_all, drt_all, node, kse, kbt, tol, maxit, XR, first):
    """``cosserat.local_strains_chord`` in lockstep: strains ``W[XR:XR+6]`` (warm start) solved in place."""
    for c in range(CHUNK):
        W[ACT, c] = 0.0 if W[FAIL, c] != 0.0 else 1.0
        W[EP, c] = 1e300
    for it in range(maxit):
        _residual(W, T, rt_all, drt_all, node, kse, kbt, XR)
        nact = 0
        nneed = 0
        for c in range(CHUNK):
            e = 0.0
            e = max(e, abs(W[FR + 0, c] / kse[0]), abs(W[FR + 3, c] / kbt[0]))
            e = max(e, abs(W[FR + 1, c] / kse[1]), abs(W[FR + 4, c] / kbt[1]))
            e = max(e, abs(W[FR + 2, c] / kse[2]), abs(W[FR + 5, c] / kbt[2]))
            act = W[ACT, c] != 0.0
            conv = e <= tol
            isnan = math.isnan(e)
            still = act and (not conv) and (not isnan)
            need = still and ((first and it == 0) or e > 0.25 * W[EP, c])
            W[FAIL, c] = 1.0 if (act and (not conv) and isnan) else W[FAIL, c]
            W[ACT, c] = 1.0 if still else 0.0
            W[NEED, c] = 1.0 if need else 0.0
            W[ER, c] = e
            nact += 1 if still else 0
            nneed += 1 if need else 0
        if nact == 0:
            return
        if nneed > 0:
            _jac_chol(W, T, rt_all, drt_all, node, kse, kbt, XR, False)
        for c in range(CHUNK):
            act = W[ACT, c] != 0.0
            W[EP, c] = W[ER, c] if act else W[EP, c]
            l00 = W[LL + 0, c]
            l10 = W[LL + 1, c]
            l11 = W[LL + 2, c]
            l20 = W[LL + 3, c]
            l21 = W[LL + 4, c]
            l22 = W[LL + 5, c]
            l30 = W[LL + 6, c]
            l31 = W[LL + 7, c]
            l32 = W[LL + 8, c]
            l33 = W[LL + 9, c]
            l40 = W[LL + 10, c]
            l41 = W[LL + 11, c]
            l42 = W[LL + 12, c]
            l43 = W[LL + 13, c]
            l44 = W[LL + 14, c]
            l50 = W[LL + 15, c]
            l51 = W[LL + 16, c]
            l52 = W[LL + 17, c]
            l53 = W[LL + 18, c]
            l54 = W[LL + 19, c]
            l55 = W[LL + 20, c]
            b0 = -W[FR + 0, c]
            b1 = -W[FR + 1, c]
            b2 = -W[FR + 2, c]
            b3 = -W[FR + 3, c]
            b4 = -W[FR + 4, c]
            b5 = -W[FR + 5, c]
            acc = b0
            b0 = acc / l00
            acc = b1
            acc -= l10 * b0
            b1 = acc / l11
            acc = b2
            acc -= l20 * b0
            acc -= l21 * b1
            b2 = acc / l22
            acc = b3
            acc -= l30 * b0
            acc -= l31 * b1
            acc -= l32 * b2
            b3 = acc / l33
            acc = b4
            acc -= l40 * b0
            acc -= l41 * b1
            acc -= l42 * b2
            acc -= l43 * b3
            b4 = acc / l44
            acc = b5
            acc -= l50 * b0
            acc -= l51 * b1
            acc -= l52 * b2
            acc -= l53 * b3
            acc -= l54 * b4
            b5 = acc / l55
            acc = b5
            b5 = acc / l55
            acc = b4
            acc -= l54 * b5
            b4 = acc / l44
            acc = b3
            acc -= l43 * b4
            acc -= l53 * b5
            b3 = acc / l33
            acc = b2
            acc -= l32 * b3
            acc -= l42 * b4
            acc -= l52 * b5
            b2 = acc / l22
            acc = b1
            acc -= l21 * b2
            acc -= l31 * b3
            acc -= l41 * b4
            acc -= l51 * b5
            b1 = acc / l11
            acc = b0
            acc -= l10 * b1
            acc -= l20 * b2
            acc -= l30 * b3
            acc -= l40 * b4
            acc -= l50 * b5
            b0 = acc / l00
            W[XR + 0, c] = W[XR + 0, c] + b0 if act else W[XR + 0, c]
            W[XR + 1, c] = W[XR + 1, c] + b1 if act else W[XR + 1, c]
            W[XR + 2, c] = W[XR + 2, c] + b2 if act else W[XR + 2, c]
            W[XR + 3, c] = W[XR + 3, c] + b3 if act else W[XR + 3, c]
            W[XR + 4, c] = W[XR + 4, c] + b4 if act else W[XR + 4, c]
            W[XR + 5, c] = W[XR + 5, c] + b5 if act else W[XR + 5, c]
    for c in range(CHUNK):  # maxit steps without convergence
        W[FAIL, c] = 1.0 if W[ACT, c] != 0.0 else W[FAIL, c]


@njit(cache=True, error_model="numpy", inline="always")
def _rk4(W, h):
    """One RK4 step of ``p' = R v``, ``R' = R [u]x`` with strains at ``X0, XM, X1`` (``cosserat._rk4_pose_step``)."""
    cc = h / 6.0
    for a in range(3):
        for c in range(CHUNK):
            q0 = W[RR + 3 * a + 0, c]
            q1 = W[RR + 3 * a + 1, c]
            q2 = W[RR + 3 * a + 2, c]
            k10 = q1 * W[X0 + 5, c] - q2 * W[X0 + 4, c]
            k11 = -q0 * W[X0 + 5, c] + q2 * W[X0 + 3, c]
            k12 = q0 * W[X0 + 4, c] - q1 * W[X0 + 3, c]
            kp1 = q0 * W[X0 + 0, c] + q1 * W[X0 + 1, c] + q2 * W[X0 + 2, c]
            s0 = q0 + 0.5 * h * k10
            s1 = q1 + 0.5 * h * k11
            s2 = q2 + 0.5 * h * k12
            k20 = s1 * W[XM + 5, c] - s2 * W[XM + 4, c]
            k21 = -s0 * W[XM + 5, c] + s2 * W[XM + 3, c]
            k22 = s0 * W[XM + 4, c] - s1 * W[XM + 3, c]
            kp2 = s0 * W[XM + 0, c] + s1 * W[XM + 1, c] + s2 * W[XM + 2, c]
            s0 = q0 + 0.5 * h * k20
            s1 = q1 + 0.5 * h * k21
            s2 = q2 + 0.5 * h * k22
            k30 = s1 * W[XM + 5, c] - s2 * W[XM + 4, c]
            k31 = -s0 * W[XM + 5, c] + s2 * W[XM + 3, c]
            k32 = s0 * W[XM + 4, c] - s1 * W[XM + 3, c]
            kp3 = s0 * W[XM + 0, c] + s1 * W[XM + 1, c] + s2 * W[XM + 2, c]
            s0 = q0 + h * k30
            s1 = q1 + h * k31
            s2 = q2 + h * k32
            k40 = s1 * W[X1 + 5, c] - s2 * W[X1 + 4, c]
            k41 = -s0 * W[X1 + 5, c] + s2 * W[X1 + 3, c]
            k42 = s0 * W[X1 + 4, c] - s1 * W[X1 + 3, c]
            kp4 = s0 * W[X1 + 0, c] + s1 * W[X1 + 1, c] + s2 * W[X1 + 2, c]
            W[RR + 3 * a + 0, c] = q0 + cc * (k10 + 2.0 * k20 + 2.0 * k30 + k40)
            W[RR + 3 * a + 1, c] = q1 + cc * (k11 + 2.0 * k21 + 2.0 * k31 + k41)
            W[RR + 3 * a + 2, c] = q2 + cc * (k12 + 2.0 * k22 + 2.0 * k32 + k42)
            W[PR + a, c] = W[PR + a, c] + cc * (kp1 + 2.0 * kp2 + 2.0 * kp3 + kp4)


@njit(cache=True, error_model="numpy", inline="always")
def _emit(W, P, Rout, b0, nb, k):
    for c in range(nb):
        for a in range(3):
            P[b0 + c, k, a] = W[PR + a, c]
            for b in range(3):
                Rout[b0 + c, k, a, b] = W[RR + 3 * a + b, c]


@njit(cache=True, error_model="numpy")
def _solve_chunk(
    taus,
    b0,
    rt_all,
    drt_all,
    ddrt_all,
    kse,
    kbt,
    length,
    n_steps,
    tol,
    maxit,
    P,
    Rout,
    status,
):
    """Configurations ``taus[b0 : b0 + CHUNK]`` (fewer at the end; the chunk is padded with the
    first one) -> ``P, Rout`` rows ``b0 ...``; ``status`` 0 = OK, 1 = needs the scalar kernel."""
    m = taus.shape[1]
    nb = min(CHUNK, taus.shape[0] - b0)
    W = np.zeros((NROWS, CHUNK))
    T = np.empty((m, CHUNK))
    for i in range(m):
        for c in range(CHUNK):
            T[i, c] = taus[b0 + (c if c < nb else 0), i]
    h = length / n_steps
    for c in range(CHUNK):
        W[X0 + 2, c] = 1.0
        W[RR + 0, c] = 1.0
        W[RR + 4, c] = 1.0
        W[RR + 8, c] = 1.0
    _chord(W, T, rt_all, drt_all, 0, kse, kbt, tol, maxit, X0, True)
    _jac_chol_slope(W, T, rt_all, drt_all, ddrt_all, 0, kse, kbt, X0, D0)
    _emit(W, P, Rout, b0, nb, 0)
    for k in range(n_steps):
        j1 = 2 * k + 2
        if k == 0:
            for a in range(6):
                for c in range(CHUNK):
                    W[X1 + a, c] = W[X0 + a, c] + h * W[D0 + a, c]
        else:
            for a in range(6):
                for c in range(CHUNK):
                    W[X1 + a, c] = (
                        5.0 * W[XA + a, c]
                        + 2.0 * h * W[DA + a, c]
                        - 4.0 * W[X0 + a, c]
                        + 4.0 * h * W[D0 + a, c]
                    )
        _chord(W, T, rt_all, drt_all, j1, kse, kbt, tol, maxit, X1, False)
        _jac_chol_slope(W, T, rt_all, drt_all, ddrt_all, j1, kse, kbt, X1, D1)
        for a in range(6):
            for c in range(CHUNK):
                W[XM + a, c] = 0.5 * (W[X0 + a, c] + W[X1 + a, c]) + 0.125 * h * (
                    W[D0 + a, c] - W[D1 + a, c]
                )
        _rk4(W, h)
        _emit(W, P, Rout, b0, nb, k + 1)
        for a in range(
            12
        ):  # XA, DA <- X0, D0 and X0, D0 <- X1, D1 (rows are consecutive)
            for c in range(CHUNK):
                W[XA + a, c] = W[X0 + a, c]
                W[X0 + a, c] = W[X1 + a, c]
    for c in range(nb):
        status[b0 + c] = 1 if W[FAIL, c] != 0.0 else 0


@njit(cache=True)
def _solve_serial(
    taus,
    rt_all,
    drt_all,
    ddrt_all,
    kse,
    kbt,
    length,
    n_steps,
    tol,
    maxit,
    P,
    Rout,
    status,
):
    nch = (taus.shape[0] + CHUNK - 1) // CHUNK
    for ch in range(nch):
        _solve_chunk(
            taus,
            ch * CHUNK,
            rt_all,
            drt_all,
            ddrt_all,
            kse,
            kbt,
            length,
            n_steps,
            tol,
            maxit,
            P,
            Rout,
            status,
        )


@njit(cache=True, parallel=True)
def _solve_parallel(
    taus,
    rt_all,
    drt_all,
    ddrt_all,
    kse,
    kbt,
    length,
    n_steps,
    tol,
    maxit,
    P,
    Rout,
    status,
):
    nch = (taus.shape[0] + CHUNK - 1) // CHUNK
    for ch in prange(nch):
        _solve_chunk(
            taus,
            ch * CHUNK,
            rt_all,
            drt_all,
            ddrt_all,
            kse,
            kbt,
            length,
            n_steps,
            tol,
            maxit,
            P,
            Rout,
            status,
        )


def solve_tensions_batch(
    robot, tensions, *, parallel: bool | None = None, validate: bool = True
):
    """Shapes of ``robot`` (no gravity) for tensions ``(B, m)`` [N], in the robot's base frame.

    Same discretisation and tolerances as :func:`cosserat.shape_free` (what
    ``TendonRobot.solve_tensions`` runs per configuration): local strain solves of eqs. (2)-(3)
    at the ``n + 1`` step nodes, Hermite midpoints from the implicit-function slope, one RK4
    pass for ``p, R`` from the identity base pose. Configurations the lockstep kernel cannot
    finish are re-solved by the scalar kernel.

    Returns ``positions (B, n+1, 3)`` and ``rotations (B, n+1, 3, 3)`` (columns = body axes).
    ``validate=False`` skips the range check (as ``TendonRobot.solve_tensions(validate=False)``,
    which ``solve_displacements`` uses for solved tensions above ``max_tension``).
    ``parallel``: split the chunks over numba's threads (default: when more than one thread is
    set). Raises :class:`InvalidInputError` for bad tensions or a robot with gravity on and
    :class:`ConvergenceError` if a configuration fails in the scalar kernel too.
    """
    from riskplan.robots.robot import LOCAL_MAXIT, LOCAL_TOL

    if robot.loaded:
        raise InvalidInputError(
            "solve_tensions_batch: the robot has gravity on; use robot.solve_tensions"
        )
    m = robot.n_tendons
    if validate:
        tau = robot._check_tensions(tensions)
    else:
        tau = np.asarray(tensions, dtype=np.float64)
    if tau.ndim != 2 or tau.shape[1] != m:
        raise InvalidInputError(f"tensions: expected shape (B, {m}), got {tau.shape}")
    tau = np.ascontiguousarray(tau, dtype=np.float64)
    B, n = tau.shape[0], robot._n + 1
    P = np.empty((B, n, 3))
    Rs = np.empty((B, n, 3, 3))
    status = np.zeros(B, dtype=np.int64)
    if B == 0:
        return P, Rs
    if parallel is None:
        parallel = get_num_threads() > 1 and B > CHUNK
    args = (
        tau,
        robot._rt,
        robot._drt,
        robot._ddrt,
        robot._kse,
        robot._kbt,
        robot._L,
        robot._n,
        LOCAL_TOL,
        LOCAL_MAXIT,
        P,
        Rs,
        status,
    )
    (_solve_parallel if parallel else _solve_serial)(*args)
    bad = np.flatnonzero(status != 0)
    if bad.size:
        sub = np.ascontiguousarray(tau[bad])
        Pb = np.empty((bad.size, n, 3))
        Rb = np.empty((bad.size, n, 3, 3))
        lengths = np.empty((bad.size, m))
        st = np.empty(bad.size, dtype=np.int64)
        cosserat.shape_free_batch(
            sub,
            robot._rt,
            robot._drt,
            robot._ddrt,
            robot._kse,
            robot._kbt,
            robot._L,
            robot._n,
            LOCAL_TOL,
            LOCAL_MAXIT,
            Pb,
            Rb,
            lengths,
            st,
        )
        if np.any(st != cosserat.OK):
            raise robot._local_failure(sub[int(np.flatnonzero(st != cosserat.OK)[0])])
        P[bad] = Pb
        Rs[bad] = Rb
    if not np.isfinite(P).all():
        b = int(np.flatnonzero(~np.isfinite(P).reshape(B, -1).all(-1))[0])
        raise ConvergenceError(f"non-finite shape for tensions {tau[b].tolist()}")
    return P, Rs
