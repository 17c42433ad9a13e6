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

# rows of the work array W (N_ROWS, CHUNK)
STRAIN = 0  # strains (v, u) at the current node
SLOPE = 6  # their slopes
STRAIN_PREV = 12  # previous node and slope, for the predictor
SLOPE_PREV = 18
STRAIN_NEXT = 24  # next node
SLOPE_NEXT = 30
STRAIN_MID = 36  # Hermite midpoint
RESIDUAL = 42  # residual of (2)-(3)
JACOBIAN = 48  # Jacobian, packed lower triangle (21), factored in place
FACTOR = 69  # Cholesky factor in use (21)
POSITION = 90  # position (3)
ROTATION = 93  # rotation, row-major (9)
ERROR = 102  # strain error of the last residual
ERROR_PREV = 103  # previous strain error (chord/refactor decision)
ACTIVE = 104  # 1.0 while the chord iteration runs
REFACTOR = 105  # 1.0 when a configuration refactors this iteration
FAILED = 106  # 1.0 when a configuration failed (scalar fallback)
N_ROWS = 107


@njit(cache=True, error_model="numpy", inline="always")
def _residual(W, T, rt_all, drt_all, node, kse, kbt, strain_row):
    """Residual of eqs. (2)-(3) at strains ``W[strain_row:strain_row+6]`` into ``W[RESIDUAL:RESIDUAL+6]`` (``cosserat.local_residual``)."""
    m = T.shape[0]
    k0 = kse[0]
    k1 = kse[1]
    k2 = kse[2]
    g0 = kbt[0]
    g1 = kbt[1]
    g2 = kbt[2]
    for c in range(CHUNK):
        W[RESIDUAL + 0, c] = k0 * W[strain_row + 0, c]
        W[RESIDUAL + 1, c] = k1 * W[strain_row + 1, c]
        W[RESIDUAL + 2, c] = k2 * (W[strain_row + 2, c] - 1.0)
        W[RESIDUAL + 3, c] = g0 * W[strain_row + 3, c]
        W[RESIDUAL + 4, c] = g1 * W[strain_row + 4, c]
        W[RESIDUAL + 5, c] = g2 * W[strain_row + 5, c]
    for i in range(m):
        r0 = rt_all[node, i, 0]
        r1 = rt_all[node, i, 1]
        r2 = rt_all[node, i, 2]
        q0 = drt_all[node, i, 0]
        q1 = drt_all[node, i, 1]
        q2 = drt_all[node, i, 2]
        for c in range(CHUNK):
            ti = T[i, c]
            x0 = W[strain_row + 0, c]
            x1 = W[strain_row + 1, c]
            x2 = W[strain_row + 2, c]
            x3 = W[strain_row + 3, c]
            x4 = W[strain_row + 4, c]
            x5 = W[strain_row + 5, c]
            w0 = x0 + x4 * r2 - x5 * r1 + q0
            w1 = x1 + x5 * r0 - x3 * r2 + q1
            w2 = x2 + x3 * r1 - x4 * r0 + q2
            sc = ti / math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
            W[RESIDUAL + 0, c] += sc * w0
            W[RESIDUAL + 1, c] += sc * w1
            W[RESIDUAL + 2, c] += sc * w2
            W[RESIDUAL + 3, c] += sc * (r1 * w2 - r2 * w1)
            W[RESIDUAL + 4, c] += sc * (r2 * w0 - r0 * w2)
            W[RESIDUAL + 5, c] += sc * (r0 * w1 - r1 * w0)


@njit(cache=True, error_model="numpy", inline="always")
def _jac_chol(W, T, rt_all, drt_all, node, kse, kbt, strain_row, always):
    """Jacobian of (2)-(3) at ``W[strain_row:strain_row+6]`` (``cosserat.local_jacobian``, lower triangle) and its
    Cholesky factor; stored into ``W[FACTOR:]`` for every configuration (``always``) or for those
    with ``W[REFACTOR] = 1``. A non-positive pivot in a stored factor marks the configuration failed."""
    m = T.shape[0]
    for c in range(CHUNK):
        for a in range(21):
            W[JACOBIAN + a, c] = 0.0
        W[JACOBIAN + 0, c] = kse[0]
        W[JACOBIAN + 2, c] = kse[1]
        W[JACOBIAN + 5, c] = kse[2]
        W[JACOBIAN + 9, c] = kbt[0]
        W[JACOBIAN + 14, c] = kbt[1]
        W[JACOBIAN + 20, c] = kbt[2]
    for i in range(m):
        r0 = rt_all[node, i, 0]
        r1 = rt_all[node, i, 1]
        r2 = rt_all[node, i, 2]
        q0 = drt_all[node, i, 0]
        q1 = drt_all[node, i, 1]
        q2 = drt_all[node, i, 2]
        for c in range(CHUNK):
            ti = T[i, c]
            x0 = W[strain_row + 0, c]
            x1 = W[strain_row + 1, c]
            x2 = W[strain_row + 2, c]
            x3 = W[strain_row + 3, c]
            x4 = W[strain_row + 4, c]
            x5 = W[strain_row + 5, c]
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
            W[JACOBIAN + 0, c] += a00
            W[JACOBIAN + 1, c] += a01
            W[JACOBIAN + 2, c] += a11
            W[JACOBIAN + 3, c] += a02
            W[JACOBIAN + 4, c] += a12
            W[JACOBIAN + 5, c] += a22
            W[JACOBIAN + 6, c] -= b00
            W[JACOBIAN + 10, c] -= b01
            W[JACOBIAN + 15, c] -= b02
            W[JACOBIAN + 7, c] -= b10
            W[JACOBIAN + 11, c] -= b11
            W[JACOBIAN + 16, c] -= b12
            W[JACOBIAN + 8, c] -= b20
            W[JACOBIAN + 12, c] -= b21
            W[JACOBIAN + 17, c] -= b22
            W[JACOBIAN + 9, c] -= -r2 * b10 + r1 * b20
            W[JACOBIAN + 13, c] -= r2 * b00 - r0 * b20
            W[JACOBIAN + 14, c] -= r2 * b01 - r0 * b21
            W[JACOBIAN + 18, c] -= -r1 * b00 + r0 * b10
            W[JACOBIAN + 19, c] -= -r1 * b01 + r0 * b11
            W[JACOBIAN + 20, c] -= -r1 * b02 + r0 * b12
    for c in range(CHUNK):
        j00 = W[JACOBIAN + 0, c]
        j10 = W[JACOBIAN + 1, c]
        j11 = W[JACOBIAN + 2, c]
        j20 = W[JACOBIAN + 3, c]
        j21 = W[JACOBIAN + 4, c]
        j22 = W[JACOBIAN + 5, c]
        j30 = W[JACOBIAN + 6, c]
        j31 = W[JACOBIAN + 7, c]
        j32 = W[JACOBIAN + 8, c]
        j33 = W[JACOBIAN + 9, c]
        j40 = W[JACOBIAN + 10, c]
        j41 = W[JACOBIAN + 11, c]
        j42 = W[JACOBIAN + 12, c]
        j43 = W[JACOBIAN + 13, c]
        j44 = W[JACOBIAN + 14, c]
        j50 = W[JACOBIAN + 15, c]
        j51 = W[JACOBIAN + 16, c]
        j52 = W[JACOBIAN + 17, c]
        j53 = W[JACOBIAN + 18, c]
        j54 = W[JACOBIAN + 19, c]
        j55 = W[JACOBIAN + 20, c]
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
        upd = always or W[REFACTOR, c] != 0.0
        W[FACTOR + 0, c] = j00 if upd else W[FACTOR + 0, c]
        W[FACTOR + 1, c] = j10 if upd else W[FACTOR + 1, c]
        W[FACTOR + 2, c] = j11 if upd else W[FACTOR + 2, c]
        W[FACTOR + 3, c] = j20 if upd else W[FACTOR + 3, c]
        W[FACTOR + 4, c] = j21 if upd else W[FACTOR + 4, c]
        W[FACTOR + 5, c] = j22 if upd else W[FACTOR + 5, c]
        W[FACTOR + 6, c] = j30 if upd else W[FACTOR + 6, c]
        W[FACTOR + 7, c] = j31 if upd else W[FACTOR + 7, c]
        W[FACTOR + 8, c] = j32 if upd else W[FACTOR + 8, c]
        W[FACTOR + 9, c] = j33 if upd else W[FACTOR + 9, c]
        W[FACTOR + 10, c] = j40 if upd else W[FACTOR + 10, c]
        W[FACTOR + 11, c] = j41 if upd else W[FACTOR + 11, c]
        W[FACTOR + 12, c] = j42 if upd else W[FACTOR + 12, c]
        W[FACTOR + 13, c] = j43 if upd else W[FACTOR + 13, c]
        W[FACTOR + 14, c] = j44 if upd else W[FACTOR + 14, c]
        W[FACTOR + 15, c] = j50 if upd else W[FACTOR + 15, c]
        W[FACTOR + 16, c] = j51 if upd else W[FACTOR + 16, c]
        W[FACTOR + 17, c] = j52 if upd else W[FACTOR + 17, c]
        W[FACTOR + 18, c] = j53 if upd else W[FACTOR + 18, c]
        W[FACTOR + 19, c] = j54 if upd else W[FACTOR + 19, c]
        W[FACTOR + 20, c] = j55 if upd else W[FACTOR + 20, c]
        fl = bad and upd
        W[FAILED, c] = 1.0 if fl else W[FAILED, c]
        W[ACTIVE, c] = 0.0 if fl else W[ACTIVE, c]


@njit(cache=True, error_model="numpy", inline="always")
def _jac_chol_slope(W, T, rt_all, drt_all, ddrt_all, node, kse, kbt, strain_row, slope_row):
    """:func:`_jac_chol` (``always``) and the strain slope (``cosserat._strain_slope``) fused: one pass over the tendons at the
    converged strains ``W[strain_row:]`` builds the Jacobian and the slope's right-hand side; the factor
    goes to ``W[FACTOR:]`` and the slope ``x' = -J^{-1} dF/ds`` to ``W[slope_row:]``. Same operations as
    ``cosserat.local_jacobian``, ``_chol_factor6`` and ``_strain_slope``."""
    m = T.shape[0]
    for c in range(CHUNK):
        for a in range(21):
            W[JACOBIAN + a, c] = 0.0
        W[JACOBIAN + 0, c] = kse[0]
        W[JACOBIAN + 2, c] = kse[1]
        W[JACOBIAN + 5, c] = kse[2]
        W[JACOBIAN + 9, c] = kbt[0]
        W[JACOBIAN + 14, c] = kbt[1]
        W[JACOBIAN + 20, c] = kbt[2]
        for a in range(6):
            W[slope_row + a, c] = 0.0
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
            x0 = W[strain_row + 0, c]
            x1 = W[strain_row + 1, c]
            x2 = W[strain_row + 2, c]
            x3 = W[strain_row + 3, c]
            x4 = W[strain_row + 4, c]
            x5 = W[strain_row + 5, c]
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
            W[JACOBIAN + 0, c] += a00
            W[JACOBIAN + 1, c] += a01
            W[JACOBIAN + 2, c] += a11
            W[JACOBIAN + 3, c] += a02
            W[JACOBIAN + 4, c] += a12
            W[JACOBIAN + 5, c] += a22
            W[JACOBIAN + 6, c] -= b00
            W[JACOBIAN + 10, c] -= b01
            W[JACOBIAN + 15, c] -= b02
            W[JACOBIAN + 7, c] -= b10
            W[JACOBIAN + 11, c] -= b11
            W[JACOBIAN + 16, c] -= b12
            W[JACOBIAN + 8, c] -= b20
            W[JACOBIAN + 12, c] -= b21
            W[JACOBIAN + 17, c] -= b22
            W[JACOBIAN + 9, c] -= -r2 * b10 + r1 * b20
            W[JACOBIAN + 13, c] -= r2 * b00 - r0 * b20
            W[JACOBIAN + 14, c] -= r2 * b01 - r0 * b21
            W[JACOBIAN + 18, c] -= -r1 * b00 + r0 * b10
            W[JACOBIAN + 19, c] -= -r1 * b01 + r0 * b11
            W[JACOBIAN + 20, c] -= -r1 * b02 + r0 * b12
            e0 = x4 * q2 - x5 * q1 + dd0
            e1 = x5 * q0 - x3 * q2 + dd1
            e2 = x3 * q1 - x4 * q0 + dd2
            td = t0 * e0 + t1 * e1 + t2 * e2
            h0 = (e0 - t0 * td) / nw
            h1 = (e1 - t1 * td) / nw
            h2 = (e2 - t2 * td) / nw
            W[slope_row + 0, c] -= ti * h0
            W[slope_row + 1, c] -= ti * h1
            W[slope_row + 2, c] -= ti * h2
            W[slope_row + 3, c] -= ti * (q1 * t2 - q2 * t1 + r1 * h2 - r2 * h1)
            W[slope_row + 4, c] -= ti * (q2 * t0 - q0 * t2 + r2 * h0 - r0 * h2)
            W[slope_row + 5, c] -= ti * (q0 * t1 - q1 * t0 + r0 * h1 - r1 * h0)
    for c in range(CHUNK):
        j00 = W[JACOBIAN + 0, c]
        j10 = W[JACOBIAN + 1, c]
        j11 = W[JACOBIAN + 2, c]
        j20 = W[JACOBIAN + 3, c]
        j21 = W[JACOBIAN + 4, c]
        j22 = W[JACOBIAN + 5, c]
        j30 = W[JACOBIAN + 6, c]
        j31 = W[JACOBIAN + 7, c]
        j32 = W[JACOBIAN + 8, c]
        j33 = W[JACOBIAN + 9, c]
        j40 = W[JACOBIAN + 10, c]
        j41 = W[JACOBIAN + 11, c]
        j42 = W[JACOBIAN + 12, c]
        j43 = W[JACOBIAN + 13, c]
        j44 = W[JACOBIAN + 14, c]
        j50 = W[JACOBIAN + 15, c]
        j51 = W[JACOBIAN + 16, c]
        j52 = W[JACOBIAN + 17, c]
        j53 = W[JACOBIAN + 18, c]
        j54 = W[JACOBIAN + 19, c]
        j55 = W[JACOBIAN + 20, c]
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
        W[FACTOR + 0, c] = j00
        W[FACTOR + 1, c] = j10
        W[FACTOR + 2, c] = j11
        W[FACTOR + 3, c] = j20
        W[FACTOR + 4, c] = j21
        W[FACTOR + 5, c] = j22
        W[FACTOR + 6, c] = j30
        W[FACTOR + 7, c] = j31
        W[FACTOR + 8, c] = j32
        W[FACTOR + 9, c] = j33
        W[FACTOR + 10, c] = j40
        W[FACTOR + 11, c] = j41
        W[FACTOR + 12, c] = j42
        W[FACTOR + 13, c] = j43
        W[FACTOR + 14, c] = j44
        W[FACTOR + 15, c] = j50
        W[FACTOR + 16, c] = j51
        W[FACTOR + 17, c] = j52
        W[FACTOR + 18, c] = j53
        W[FACTOR + 19, c] = j54
        W[FACTOR + 20, c] = j55
        W[FAILED, c] = 1.0 if bad else W[FAILED, c]
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
        b0 = W[slope_row + 0, c]
        b1 = W[slope_row + 1, c]
        b2 = W[slope_row + 2, c]
        b3 = W[slope_row + 3, c]
        b4 = W[slope_row + 4, c]
        b5 = W[slope_row + 5, c]
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
        W[slope_row + 0, c] = b0
        W[slope_row + 1, c] = b1
        W[slope_row + 2, c] = b2
        W[slope_row + 3, c] = b3
        W[slope_row + 4, c] = b4
        W[slope_row + 5, c] = b5


@njit(cache=True, error_model="numpy", inline="always")
def _chord(W, T, rt_all, drt_all, node, kse, kbt, tol, maxit, strain_row, first):
    """``cosserat.local_strains_chord`` in lockstep: strains ``W[strain_row:strain_row+6]`` (warm start) solved in place."""
    for c in range(CHUNK):
        W[ACTIVE, c] = 0.0 if W[FAILED, c] != 0.0 else 1.0
        W[ERROR_PREV, c] = 1e300
    for it in range(maxit):
        _residual(W, T, rt_all, drt_all, node, kse, kbt, strain_row)
        nact = 0
        nneed = 0
        for c in range(CHUNK):
            e = 0.0
            e = max(e, abs(W[RESIDUAL + 0, c] / kse[0]), abs(W[RESIDUAL + 3, c] / kbt[0]))
            e = max(e, abs(W[RESIDUAL + 1, c] / kse[1]), abs(W[RESIDUAL + 4, c] / kbt[1]))
            e = max(e, abs(W[RESIDUAL + 2, c] / kse[2]), abs(W[RESIDUAL + 5, c] / kbt[2]))
            act = W[ACTIVE, c] != 0.0
            conv = e <= tol
            isnan = math.isnan(e)
            still = act and (not conv) and (not isnan)
            need = still and ((first and it == 0) or e > 0.25 * W[ERROR_PREV, c])
            W[FAILED, c] = 1.0 if (act and (not conv) and isnan) else W[FAILED, c]
            W[ACTIVE, c] = 1.0 if still else 0.0
            W[REFACTOR, c] = 1.0 if need else 0.0
            W[ERROR, c] = e
            nact += 1 if still else 0
            nneed += 1 if need else 0
        if nact == 0:
            return
        if nneed > 0:
            _jac_chol(W, T, rt_all, drt_all, node, kse, kbt, strain_row, False)
        for c in range(CHUNK):
            act = W[ACTIVE, c] != 0.0
            W[ERROR_PREV, c] = W[ERROR, c] if act else W[ERROR_PREV, c]
            l00 = W[FACTOR + 0, c]
            l10 = W[FACTOR + 1, c]
            l11 = W[FACTOR + 2, c]
            l20 = W[FACTOR + 3, c]
            l21 = W[FACTOR + 4, c]
            l22 = W[FACTOR + 5, c]
            l30 = W[FACTOR + 6, c]
            l31 = W[FACTOR + 7, c]
            l32 = W[FACTOR + 8, c]
            l33 = W[FACTOR + 9, c]
            l40 = W[FACTOR + 10, c]
            l41 = W[FACTOR + 11, c]
            l42 = W[FACTOR + 12, c]
            l43 = W[FACTOR + 13, c]
            l44 = W[FACTOR + 14, c]
            l50 = W[FACTOR + 15, c]
            l51 = W[FACTOR + 16, c]
            l52 = W[FACTOR + 17, c]
            l53 = W[FACTOR + 18, c]
            l54 = W[FACTOR + 19, c]
            l55 = W[FACTOR + 20, c]
            b0 = -W[RESIDUAL + 0, c]
            b1 = -W[RESIDUAL + 1, c]
            b2 = -W[RESIDUAL + 2, c]
            b3 = -W[RESIDUAL + 3, c]
            b4 = -W[RESIDUAL + 4, c]
            b5 = -W[RESIDUAL + 5, c]
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
            W[strain_row + 0, c] = W[strain_row + 0, c] + b0 if act else W[strain_row + 0, c]
            W[strain_row + 1, c] = W[strain_row + 1, c] + b1 if act else W[strain_row + 1, c]
            W[strain_row + 2, c] = W[strain_row + 2, c] + b2 if act else W[strain_row + 2, c]
            W[strain_row + 3, c] = W[strain_row + 3, c] + b3 if act else W[strain_row + 3, c]
            W[strain_row + 4, c] = W[strain_row + 4, c] + b4 if act else W[strain_row + 4, c]
            W[strain_row + 5, c] = W[strain_row + 5, c] + b5 if act else W[strain_row + 5, c]
    for c in range(CHUNK):  # maxit steps without convergence
        W[FAILED, c] = 1.0 if W[ACTIVE, c] != 0.0 else W[FAILED, c]


@njit(cache=True, error_model="numpy", inline="always")
def _rk4(W, h):
    """One RK4 step of ``p' = R v``, ``R' = R [u]x`` with strains at ``STRAIN, STRAIN_MID, STRAIN_NEXT`` (``cosserat._rk4_pose_step``)."""
    cc = h / 6.0
    for a in range(3):
        for c in range(CHUNK):
            q0 = W[ROTATION + 3 * a + 0, c]
            q1 = W[ROTATION + 3 * a + 1, c]
            q2 = W[ROTATION + 3 * a + 2, c]
            k10 = q1 * W[STRAIN + 5, c] - q2 * W[STRAIN + 4, c]
            k11 = -q0 * W[STRAIN + 5, c] + q2 * W[STRAIN + 3, c]
            k12 = q0 * W[STRAIN + 4, c] - q1 * W[STRAIN + 3, c]
            kp1 = q0 * W[STRAIN + 0, c] + q1 * W[STRAIN + 1, c] + q2 * W[STRAIN + 2, c]
            s0 = q0 + 0.5 * h * k10
            s1 = q1 + 0.5 * h * k11
            s2 = q2 + 0.5 * h * k12
            k20 = s1 * W[STRAIN_MID + 5, c] - s2 * W[STRAIN_MID + 4, c]
            k21 = -s0 * W[STRAIN_MID + 5, c] + s2 * W[STRAIN_MID + 3, c]
            k22 = s0 * W[STRAIN_MID + 4, c] - s1 * W[STRAIN_MID + 3, c]
            kp2 = s0 * W[STRAIN_MID + 0, c] + s1 * W[STRAIN_MID + 1, c] + s2 * W[STRAIN_MID + 2, c]
            s0 = q0 + 0.5 * h * k20
            s1 = q1 + 0.5 * h * k21
            s2 = q2 + 0.5 * h * k22
            k30 = s1 * W[STRAIN_MID + 5, c] - s2 * W[STRAIN_MID + 4, c]
            k31 = -s0 * W[STRAIN_MID + 5, c] + s2 * W[STRAIN_MID + 3, c]
            k32 = s0 * W[STRAIN_MID + 4, c] - s1 * W[STRAIN_MID + 3, c]
            kp3 = s0 * W[STRAIN_MID + 0, c] + s1 * W[STRAIN_MID + 1, c] + s2 * W[STRAIN_MID + 2, c]
            s0 = q0 + h * k30
            s1 = q1 + h * k31
            s2 = q2 + h * k32
            k40 = s1 * W[STRAIN_NEXT + 5, c] - s2 * W[STRAIN_NEXT + 4, c]
            k41 = -s0 * W[STRAIN_NEXT + 5, c] + s2 * W[STRAIN_NEXT + 3, c]
            k42 = s0 * W[STRAIN_NEXT + 4, c] - s1 * W[STRAIN_NEXT + 3, c]
            kp4 = s0 * W[STRAIN_NEXT + 0, c] + s1 * W[STRAIN_NEXT + 1, c] + s2 * W[STRAIN_NEXT + 2, c]
            W[ROTATION + 3 * a + 0, c] = q0 + cc * (k10 + 2.0 * k20 + 2.0 * k30 + k40)
            W[ROTATION + 3 * a + 1, c] = q1 + cc * (k11 + 2.0 * k21 + 2.0 * k31 + k41)
            W[ROTATION + 3 * a + 2, c] = q2 + cc * (k12 + 2.0 * k22 + 2.0 * k32 + k42)
            W[POSITION + a, c] = W[POSITION + a, c] + cc * (kp1 + 2.0 * kp2 + 2.0 * kp3 + kp4)


@njit(cache=True, error_model="numpy", inline="always")
def _emit(W, P, Rout, b0, nb, k):
    for c in range(nb):
        for a in range(3):
            P[b0 + c, k, a] = W[POSITION + a, c]
            for b in range(3):
                Rout[b0 + c, k, a, b] = W[ROTATION + 3 * a + b, c]


@njit(cache=True, error_model="numpy")
def _solve_chunk(taus, b0, rod, tol, maxit, P, Rout, status):
    """Configurations ``taus[b0 : b0 + CHUNK]`` (fewer at the end; the chunk is padded with the
    first one) -> ``P, Rout`` rows ``b0 ...``; ``status`` 0 = OK, 1 = needs the scalar kernel."""
    rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps = rod
    m = taus.shape[1]
    nb = min(CHUNK, taus.shape[0] - b0)
    W = np.zeros((N_ROWS, CHUNK))
    T = np.empty((m, CHUNK))
    for i in range(m):
        for c in range(CHUNK):
            T[i, c] = taus[b0 + (c if c < nb else 0), i]
    h = length / n_steps
    for c in range(CHUNK):
        W[STRAIN + 2, c] = 1.0
        W[ROTATION + 0, c] = 1.0
        W[ROTATION + 4, c] = 1.0
        W[ROTATION + 8, c] = 1.0
    _chord(W, T, rt_all, drt_all, 0, kse, kbt, tol, maxit, STRAIN, True)
    _jac_chol_slope(W, T, rt_all, drt_all, ddrt_all, 0, kse, kbt, STRAIN, SLOPE)
    _emit(W, P, Rout, b0, nb, 0)
    for k in range(n_steps):
        j1 = 2 * k + 2
        if k == 0:
            for a in range(6):
                for c in range(CHUNK):
                    W[STRAIN_NEXT + a, c] = W[STRAIN + a, c] + h * W[SLOPE + a, c]
        else:
            for a in range(6):
                for c in range(CHUNK):
                    W[STRAIN_NEXT + a, c] = (
                        5.0 * W[STRAIN_PREV + a, c]
                        + 2.0 * h * W[SLOPE_PREV + a, c]
                        - 4.0 * W[STRAIN + a, c]
                        + 4.0 * h * W[SLOPE + a, c]
                    )
        _chord(W, T, rt_all, drt_all, j1, kse, kbt, tol, maxit, STRAIN_NEXT, False)
        _jac_chol_slope(W, T, rt_all, drt_all, ddrt_all, j1, kse, kbt, STRAIN_NEXT, SLOPE_NEXT)
        for a in range(6):
            for c in range(CHUNK):
                W[STRAIN_MID + a, c] = 0.5 * (W[STRAIN + a, c] + W[STRAIN_NEXT + a, c]) + 0.125 * h * (
                    W[SLOPE + a, c] - W[SLOPE_NEXT + a, c]
                )
        _rk4(W, h)
        _emit(W, P, Rout, b0, nb, k + 1)
        for a in range(
            12
        ):  # STRAIN_PREV, SLOPE_PREV <- STRAIN, SLOPE and STRAIN, SLOPE <- STRAIN_NEXT, SLOPE_NEXT (rows are consecutive)
            for c in range(CHUNK):
                W[STRAIN_PREV + a, c] = W[STRAIN + a, c]
                W[STRAIN + a, c] = W[STRAIN_NEXT + a, c]
    for c in range(nb):
        status[b0 + c] = 1 if W[FAILED, c] != 0.0 else 0


@njit(cache=True)
def _solve_serial(taus, rod, tol, maxit, P, Rout, status):
    nch = (taus.shape[0] + CHUNK - 1) // CHUNK
    for ch in range(nch):
        _solve_chunk(taus, ch * CHUNK, rod, tol, maxit, P, Rout, status)


@njit(cache=True, parallel=True)
def _solve_parallel(taus, rod, tol, maxit, P, Rout, status):
    nch = (taus.shape[0] + CHUNK - 1) // CHUNK
    for ch in prange(nch):
        _solve_chunk(taus, ch * CHUNK, rod, tol, maxit, P, Rout, status)


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
        tau = robot.check_tensions(tensions)
    else:
        tau = np.asarray(tensions, dtype=np.float64)
    if tau.ndim != 2 or tau.shape[1] != m:
        raise InvalidInputError(f"tensions: expected shape (B, {m}), got {tau.shape}")
    tau = np.ascontiguousarray(tau, dtype=np.float64)
    B, n = tau.shape[0], robot.n_stations
    P = np.empty((B, n, 3))
    Rs = np.empty((B, n, 3, 3))
    status = np.zeros(B, dtype=np.int64)
    if B == 0:
        return P, Rs
    if parallel is None:
        parallel = get_num_threads() > 1 and B > CHUNK
    args = (tau, robot.tables, LOCAL_TOL, LOCAL_MAXIT, P, Rs, status)
    (_solve_parallel if parallel else _solve_serial)(*args)
    bad = np.flatnonzero(status != 0)
    if bad.size:
        sub = np.ascontiguousarray(tau[bad])
        Pb = np.empty((bad.size, n, 3))
        Rb = np.empty((bad.size, n, 3, 3))
        lengths = np.empty((bad.size, m))
        st = np.empty(bad.size, dtype=np.int64)
        cosserat.shape_free_batch(sub, robot.tables, LOCAL_TOL, LOCAL_MAXIT, Pb, Rb, lengths, st)
        if np.any(st != cosserat.OK):
            raise robot.local_failure_error(sub[int(np.flatnonzero(st != cosserat.OK)[0])])
        P[bad] = Pb
        Rs[bad] = Rb
    if not np.isfinite(P).all():
        b = int(np.flatnonzero(~np.isfinite(P).reshape(B, -1).all(-1))[0])
        raise ConvergenceError(f"non-finite shape for tensions {tau[b].tolist()}")
    return P, Rs
