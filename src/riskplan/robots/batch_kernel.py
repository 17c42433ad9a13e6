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
operation in the same order, so results agree with it bit for bit (tested).

One source for the arithmetic: the per-tendon terms (``strains.tendon_tangent``,
``unit_tangent``, ``tendon_stiffness``, ``tendon_slope_source``) and the RK4 row step
(``integration.rk4_row``) are the scalar kernels' own inline helpers, fed here with one
configuration's column of ``W``.

Repetition that is deliberate (a duplicate-code scan lists it):

* the 6x6 Cholesky factor and solve on the packed lower triangle of a column of ``W``
  (``linalg6.packed_chol_factor6``, ``packed_chol_solve6``, beside the scalar kernel's loops
  that do the same operations in the same order) are unrolled, row after row of the same
  shape, so that LLVM keeps the 21 entries in registers and vectorises across the chunk;
* ``_jac_chol_slope`` repeats the tendon loop of ``_jac_chol`` because it fuses the
  Jacobian and the slope's right-hand side into one pass over the tendons (calling both
  would evaluate every tendon tangent twice per node);
* the six rows of a strain vector are written one statement each (``W[row + 0, c] = b0`` ...)
  because the 6x6 solve returns scalars, not an array (no allocation in the loop);
* ``_solve_serial`` and ``_solve_parallel`` differ only in ``range`` / ``prange``:
  numba compiles a parallel loop only in a function of its own.

Tendon path lengths are not computed (the shape needs none).
"""

from __future__ import annotations

import math

import numpy as np
from numba import get_num_threads, njit, prange

from riskplan.errors import ConvergenceError, InvalidInputError
from riskplan.robots import cosserat
from riskplan.robots.integration import rk4_row
from riskplan.robots.linalg6 import packed_chol_factor6, packed_chol_solve6
from riskplan.robots.rod_tables import LOCAL_MAXIT, LOCAL_TOL, RodTables
from riskplan.robots.strains import (
    tendon_slope_source,
    tendon_stiffness,
    tendon_tangent,
    unit_tangent,
)

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
def _strains(W, row, c):
    """Strains ``(v, u)`` of configuration ``c`` stored at ``W[row : row + 6, c]``, as a 6-tuple."""
    return (
        W[row + 0, c],
        W[row + 1, c],
        W[row + 2, c],
        W[row + 3, c],
        W[row + 4, c],
        W[row + 5, c],
    )


@njit(cache=True, error_model="numpy", inline="always")
def _residual(W, T, rt_all, drt_all, node, kse, kbt, strain_row):
    """Residual of eqs. (2)-(3) at strains ``W[strain_row:strain_row+6]`` into ``W[RESIDUAL:RESIDUAL+6]`` (``strains.local_residual``)."""
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
        r = (r0, r1, r2)
        q = (drt_all[node, i, 0], drt_all[node, i, 1], drt_all[node, i, 2])
        for c in range(CHUNK):
            ti = T[i, c]
            w0, w1, w2 = tendon_tangent(_strains(W, strain_row, c), r, q)
            sc = ti / math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
            W[RESIDUAL + 0, c] += sc * w0
            W[RESIDUAL + 1, c] += sc * w1
            W[RESIDUAL + 2, c] += sc * w2
            W[RESIDUAL + 3, c] += sc * (r1 * w2 - r2 * w1)
            W[RESIDUAL + 4, c] += sc * (r2 * w0 - r0 * w2)
            W[RESIDUAL + 5, c] += sc * (r0 * w1 - r1 * w0)


@njit(cache=True, error_model="numpy", inline="always")
def _jacobian_reset(W, kse, kbt):
    """``W[JACOBIAN:JACOBIAN+21] = diag(K_se, K_bt)`` (packed lower triangle, row by row)."""
    for c in range(CHUNK):
        for a in range(21):
            W[JACOBIAN + a, c] = 0.0
        W[JACOBIAN + 0, c] = kse[0]
        W[JACOBIAN + 2, c] = kse[1]
        W[JACOBIAN + 5, c] = kse[2]
        W[JACOBIAN + 9, c] = kbt[0]
        W[JACOBIAN + 14, c] = kbt[1]
        W[JACOBIAN + 20, c] = kbt[2]


@njit(cache=True, error_model="numpy", inline="always")
def _jacobian_add_tendon(W, c, sc, t0, t1, t2, r):
    """Add one tendon's blocks (``strains.tendon_stiffness``) to configuration ``c``'s packed
    Jacobian: ``A`` to the K_se block, ``-Bm`` / ``-Bm^T`` off the diagonal, ``H`` to K_bt."""
    r0 = r[0]
    r1 = r[1]
    r2 = r[2]
    a00, a11, a22, a01, a02, a12, b00, b01, b02, b10, b11, b12, b20, b21, b22 = tendon_stiffness(
        sc, t0, t1, t2, r
    )
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


@njit(cache=True, error_model="numpy", inline="always")
def _jac_chol(W, T, rt_all, drt_all, node, kse, kbt, strain_row, always):
    """Jacobian of (2)-(3) at ``W[strain_row:strain_row+6]`` (``strains.local_jacobian``, lower triangle) and its
    Cholesky factor; stored into ``W[FACTOR:]`` for every configuration (``always``) or for those
    with ``W[REFACTOR] = 1``. A non-positive pivot in a stored factor marks the configuration failed."""
    m = T.shape[0]
    _jacobian_reset(W, kse, kbt)
    for i in range(m):
        r = (rt_all[node, i, 0], rt_all[node, i, 1], rt_all[node, i, 2])
        q = (drt_all[node, i, 0], drt_all[node, i, 1], drt_all[node, i, 2])
        for c in range(CHUNK):
            ti = T[i, c]
            nw, t0, t1, t2 = unit_tangent(_strains(W, strain_row, c), r, q)
            _jacobian_add_tendon(W, c, ti / nw, t0, t1, t2, r)
    for c in range(CHUNK):
        upd = always or W[REFACTOR, c] != 0.0
        bad = packed_chol_factor6(W, c, JACOBIAN, FACTOR, upd)
        fl = bad and upd
        W[FAILED, c] = 1.0 if fl else W[FAILED, c]
        W[ACTIVE, c] = 0.0 if fl else W[ACTIVE, c]


@njit(cache=True, error_model="numpy", inline="always")
def _jac_chol_slope(W, T, rt_all, drt_all, ddrt_all, node, kse, kbt, strain_row, slope_row):
    """:func:`_jac_chol` (``always``) and the strain slope (``strains.strain_slope``) fused: one
    pass over the tendons at the converged strains ``W[strain_row:]`` builds the Jacobian and
    the slope's right-hand side; the factor goes to ``W[FACTOR:]`` and the slope
    ``x' = -J^{-1} dF/ds`` to ``W[slope_row:]``."""
    m = T.shape[0]
    _jacobian_reset(W, kse, kbt)
    for c in range(CHUNK):
        for a in range(6):
            W[slope_row + a, c] = 0.0
    for i in range(m):
        r = (rt_all[node, i, 0], rt_all[node, i, 1], rt_all[node, i, 2])
        q = (drt_all[node, i, 0], drt_all[node, i, 1], drt_all[node, i, 2])
        dd = (ddrt_all[node, i, 0], ddrt_all[node, i, 1], ddrt_all[node, i, 2])
        for c in range(CHUNK):
            ti = T[i, c]
            x = _strains(W, strain_row, c)
            nw, t0, t1, t2 = unit_tangent(x, r, q)
            _jacobian_add_tendon(W, c, ti / nw, t0, t1, t2, r)
            src = tendon_slope_source(ti, nw, t0, t1, t2, x, r, q, dd)
            for a in range(6):  # unrolled by LLVM (constant trip count and tuple index)
                W[slope_row + a, c] -= src[a]
    for c in range(CHUNK):
        bad = packed_chol_factor6(W, c, JACOBIAN, FACTOR, True)
        W[FAILED, c] = 1.0 if bad else W[FAILED, c]
        b0, b1, b2, b3, b4, b5 = packed_chol_solve6(
            W, c, FACTOR, W[slope_row + 0, c], W[slope_row + 1, c], W[slope_row + 2, c],
            W[slope_row + 3, c], W[slope_row + 4, c], W[slope_row + 5, c],
        )  # fmt: skip
        W[slope_row + 0, c] = b0
        W[slope_row + 1, c] = b1
        W[slope_row + 2, c] = b2
        W[slope_row + 3, c] = b3
        W[slope_row + 4, c] = b4
        W[slope_row + 5, c] = b5


@njit(cache=True, error_model="numpy", inline="always")
def _chord(W, T, rt_all, drt_all, node, kse, kbt, tol, maxit, strain_row, first):
    """``strains.local_strains_chord`` in lockstep: strains ``W[strain_row:strain_row+6]`` (warm start) solved in place."""
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
            b0, b1, b2, b3, b4, b5 = packed_chol_solve6(
                W, c, FACTOR, -W[RESIDUAL + 0, c], -W[RESIDUAL + 1, c], -W[RESIDUAL + 2, c],
                -W[RESIDUAL + 3, c], -W[RESIDUAL + 4, c], -W[RESIDUAL + 5, c],
            )  # fmt: skip
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
    """One RK4 step of ``p' = R v``, ``R' = R [u]x`` with strains at ``STRAIN, STRAIN_MID,
    STRAIN_NEXT`` (``integration.rk4_row``, as in ``integration.rk4_pose_step``)."""
    for a in range(3):
        for c in range(CHUNK):
            n0, n1, n2, dp = rk4_row(
                W[ROTATION + 3 * a + 0, c], W[ROTATION + 3 * a + 1, c], W[ROTATION + 3 * a + 2, c],
                _strains(W, STRAIN, c), _strains(W, STRAIN_MID, c), _strains(W, STRAIN_NEXT, c), h,
            )  # fmt: skip
            W[ROTATION + 3 * a + 0, c] = n0
            W[ROTATION + 3 * a + 1, c] = n1
            W[ROTATION + 3 * a + 2, c] = n2
            W[POSITION + a, c] = W[POSITION + a, c] + dp


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
        W[STRAIN_NEXT + 2, c] = 1.0  # the base station's start: the straight rod
        W[ROTATION + 0, c] = 1.0
        W[ROTATION + 4, c] = 1.0
        W[ROTATION + 8, c] = 1.0
    # one loop over the stations, the base included, each solved in the STRAIN_NEXT rows: the
    # inline chord and slope stages then have one call site each (numba types and lowers an
    # inline function once per call site, and this kernel is most of a cold cache's compile)
    for k in range(n_steps + 1):
        if k == 1:
            for a in range(6):
                for c in range(CHUNK):
                    W[STRAIN_NEXT + a, c] = W[STRAIN + a, c] + h * W[SLOPE + a, c]
        elif k > 1:
            for a in range(6):
                for c in range(CHUNK):
                    W[STRAIN_NEXT + a, c] = (
                        5.0 * W[STRAIN_PREV + a, c]
                        + 2.0 * h * W[SLOPE_PREV + a, c]
                        - 4.0 * W[STRAIN + a, c]
                        + 4.0 * h * W[SLOPE + a, c]
                    )
        _chord(W, T, rt_all, drt_all, 2 * k, kse, kbt, tol, maxit, STRAIN_NEXT, k == 0)
        _jac_chol_slope(W, T, rt_all, drt_all, ddrt_all, 2 * k, kse, kbt, STRAIN_NEXT, SLOPE_NEXT)
        if k > 0:
            for a in range(6):
                for c in range(CHUNK):
                    W[STRAIN_MID + a, c] = 0.5 * (
                        W[STRAIN + a, c] + W[STRAIN_NEXT + a, c]
                    ) + 0.125 * h * (W[SLOPE + a, c] - W[SLOPE_NEXT + a, c])
            _rk4(W, h)
        _emit(W, P, Rout, b0, nb, k)
        # STRAIN_PREV, SLOPE_PREV <- STRAIN, SLOPE and STRAIN, SLOPE <- STRAIN_NEXT, SLOPE_NEXT
        # (the rows are consecutive)
        for a in range(12):
            for c in range(CHUNK):
                W[STRAIN_PREV + a, c] = W[STRAIN + a, c]
                W[STRAIN + a, c] = W[STRAIN_NEXT + a, c]
    for c in range(nb):
        status[b0 + c] = 1 if W[FAILED, c] != 0.0 else 0


@njit(cache=True)
def _solve_serial(
    taus, rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps, tol, maxit, P, Rout, status
):
    rod = RodTables(rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps)
    nch = (taus.shape[0] + CHUNK - 1) // CHUNK
    for ch in range(nch):
        _solve_chunk(taus, ch * CHUNK, rod, tol, maxit, P, Rout, status)


@njit(cache=True, parallel=True)
def _solve_parallel(
    taus, rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps, tol, maxit, P, Rout, status
):
    rod = RodTables(rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps)
    nch = (taus.shape[0] + CHUNK - 1) // CHUNK
    for ch in prange(nch):
        _solve_chunk(taus, ch * CHUNK, rod, tol, maxit, P, Rout, status)


def solve_tensions_batch(robot, tensions, *, parallel: bool | None = None, validate: bool = True):
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

    Parameters
    ----------
    robot : TendonRobot
        A robot with gravity off.
    tensions : array_like, shape (B, m)
        Tensions [N].
    parallel : bool, optional
        Split the chunks over numba's threads.
    validate : bool
        Check the tensions' range.

    Returns
    -------
    positions : numpy.ndarray
        ``(B, n + 1, 3)`` [m], base frame.
    rotations : numpy.ndarray
        ``(B, n + 1, 3, 3)``, columns the body axes.
    """
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
    args = (tau, *robot.tables, LOCAL_TOL, LOCAL_MAXIT, P, Rs, status)
    (_solve_parallel if parallel else _solve_serial)(*args)
    bad = np.flatnonzero(status != 0)
    if bad.size:
        sub = np.ascontiguousarray(tau[bad])
        Pb = np.empty((bad.size, n, 3))
        Rb = np.empty((bad.size, n, 3, 3))
        lengths = np.empty((bad.size, m))
        st = np.empty(bad.size, dtype=np.int64)
        cosserat.shape_free_batch(sub, *robot.tables, LOCAL_TOL, LOCAL_MAXIT, Pb, Rb, lengths, st)
        if np.any(st != cosserat.OK):
            raise robot.local_failure_error(sub[int(np.flatnonzero(st != cosserat.OK)[0])])
        P[bad] = Pb
        Rs[bad] = Rb
    if not np.isfinite(P).all():
        b = int(np.flatnonzero(~np.isfinite(P).reshape(B, -1).all(-1))[0])
        raise ConvergenceError(f"non-finite shape for tensions {tau[b].tolist()}")
    return P, Rs
