"""Integration of the rod along s: one RK4 pass of ``p' = R v``, ``R' = R [u]x`` with the
local strains solved at the step nodes (no external loads: :func:`shape_free`), and the
loaded case (gravity, tip loads) that integrates the resultants ``N, M`` too
(:func:`shape_loaded`, shot on the base values by ``TendonRobot``). Equations: module
docstring of :mod:`riskplan.robots.cosserat`.

:func:`rk4_row` takes the four RK4 stages as four calls of one inline rate function: the
twelve stage values stay scalars in registers, with no stage loop or temporary array (the
operations and their order are those of the stages written out), and the same inline
function serves the scalar pass (:func:`rk4_pose_step`)
and the lockstep kernel of :mod:`riskplan.robots.batch_kernel`, which vectorises it across
configurations. The entry points called from Python (:func:`shape_free`,
:func:`shape_free_batch`, :func:`shape_loaded`) list the seven
:class:`~riskplan.robots.rod_tables.RodTables` fields as separate arguments, as the
displacement solve's do: plain arrays cross the Python boundary ten times faster than a named
tuple (see that module), so these parameter lists repeat by design.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from riskplan.robots.linalg6 import chol_factor6
from riskplan.robots.rod_tables import LOCAL_FAIL, OK, RodTables
from riskplan.robots.strains import (
    local_jacobian,
    local_strains,
    local_strains_chord,
    strain_slope,
    tendon_speeds,
)


@njit(cache=True, inline="always")
def _row_rate(s0, s1, s2, x):
    """The rates of one row ``q = (s0, s1, s2)`` of ``R`` at strains ``x = (v, u)``: the row of
    ``R [u]x`` and the position component ``q . v``, as four scalars."""
    return (
        s1 * x[5] - s2 * x[4],
        -s0 * x[5] + s2 * x[3],
        s0 * x[4] - s1 * x[3],
        s0 * x[0] + s1 * x[1] + s2 * x[2],
    )


@njit(cache=True, inline="always")
def rk4_row(q0, q1, q2, x0, xm, x1, h):
    """One classical RK4 step of one row ``q`` of ``R`` under ``q' = q [u]x`` and of the matching
    position component under ``p_a' = q . v``, with strains ``x0, xm, x1`` (indexable, 6) at
    ``s, s + h/2, s + h``. Returns the new row and the position increment. Shared by
    :func:`rk4_pose_step` and the lockstep kernel.

    The four stages are one loop (LLVM unrolls it; numba types and lowers the rate function
    once instead of four times, which a first call feels). The weighted sums start from
    ``-0.0``, the exact additive identity, so they add ``k1 + 2 k2 + 2 k3 + k4`` in that order
    and to the bit as the stages written out.
    """
    a = 0.5 * h
    s0, s1, s2 = q0, q1, q2  # the point the stage's rate is taken at
    n0 = n1 = n2 = dp = -0.0
    for st in range(4):
        x = x0 if st == 0 else (xm if st < 3 else x1)
        k0, k1, k2, kp = _row_rate(s0, s1, s2, x)
        w = 2.0 if st == 1 or st == 2 else 1.0
        n0 += w * k0
        n1 += w * k1
        n2 += w * k2
        dp += w * kp
        step = a if st < 2 else h
        s0 = q0 + step * k0
        s1 = q1 + step * k1
        s2 = q2 + step * k2
    c = h / 6.0
    return q0 + c * n0, q1 + c * n1, q2 + c * n2, c * dp


@njit(cache=True, inline="always")
def rk4_pose_step(p, R, x0, xm, x1, h, pn, Rn):
    """Classical RK4 step of ``p' = R v``, ``R' = R [u]x`` with strains known at s, s+h/2, s+h.

    The ODE is linear in ``(p, R)`` row by row, so each row of ``R`` is stepped independently.
    """
    for a in range(3):
        n0, n1, n2, dp = rk4_row(R[a, 0], R[a, 1], R[a, 2], x0, xm, x1, h)
        Rn[a, 0] = n0
        Rn[a, 1] = n1
        Rn[a, 2] = n2
        pn[a] = p[a] + dp


@njit(cache=True)
def pose_from_node_strains(xs, h, n_steps, p_out, R_out):
    """Positions ``p_out (n+1, 3)`` and frames ``R_out (n+1, 3, 3)`` (base frame, from the
    identity at ``s = 0``) by ``n`` RK4 steps (:func:`rk4_pose_step`) of ``p' = R v``,
    ``R' = R [u]x`` with the strains ``xs (2n+1, 6)`` solved at every RK4 node ``s = j h / 2``
    (the displacement solve's length pass leaves them,
    :func:`~riskplan.robots.tendon_lengths.lengths_and_jacobian`). :func:`shape_free` takes the
    same steps with Hermite-interpolated half-step strains; the two passes differ by O(h^4).
    One call site of the inline step, so that a first call types and lowers it once.
    """
    for a in range(3):
        p_out[0, a] = 0.0
        for b in range(3):
            R_out[0, a, b] = 1.0 if a == b else 0.0
    for k in range(n_steps):
        j = 2 * k
        rk4_pose_step(
            p_out[k], R_out[k], xs[j], xs[j + 1], xs[j + 2], h, p_out[k + 1], R_out[k + 1]
        )


@njit(cache=True)
def pose_derivative(R, x, dR, dp):
    u0 = x[3]
    u1 = x[4]
    u2 = x[5]
    for a in range(3):
        dp[a] = R[a, 0] * x[0] + R[a, 1] * x[1] + R[a, 2] * x[2]
        # R [u]x, columns: R(u x e_j)
        dR[a, 0] = R[a, 1] * u2 - R[a, 2] * u1
        dR[a, 1] = -R[a, 0] * u2 + R[a, 2] * u0
        dR[a, 2] = R[a, 0] * u1 - R[a, 1] * u0


@njit(cache=True, error_model="numpy")
def shape_free(
    tau,
    rt_all,
    drt_all,
    ddrt_all,
    kse,
    kbt,
    length,
    n_steps,
    tol,
    maxit,
    p_out,
    R_out,
    x_out,
    lengths,
):
    """Shape under tendon tensions ``tau (m,)`` without external loads (no shooting).

    Strains solve (2)-(3) at the step nodes only; their slopes ``x'`` follow from the implicit
    function theorem (:func:`strain_slope`), and the half-step strains RK4 needs come from the
    cubic Hermite interpolant ``x_m = (x_0 + x_1)/2 + h (x_0' - x_1')/8`` (error O(h^4), so the
    pass stays 4th order). The next node's Newton start is the Hermite extrapolation
    ``5 x_{k-1} + 2h x'_{k-1} - 4 x_k + 4h x'_k``; Newton reuses the fresh factor of the
    previous node (chord) and refactors only if it converges slowly.

    Outputs: ``p_out (n+1, 3)``, ``R_out (n+1, 3, 3)`` (base frame), strains ``x_out (n+1, 6)``,
    tendon path lengths ``lengths (m,)`` (Simpson). Returns a status code. The seven arguments after
    ``tau`` are the fields of :class:`~riskplan.robots.rod_tables.RodTables`: call it as
    ``shape_free(tau, *robot.tables, tol, maxit, ...)`` (numba types plain arrays much faster
    than a named tuple at the Python boundary).

    One loop over the stations, the base included, so that each inline helper has one call
    site: numba types and lowers an inline helper once per call site, and a first call
    compiles this kernel (see :mod:`riskplan.robots.cosserat`).
    """
    m = tau.shape[0]
    h = length / n_steps
    F = np.empty(6)
    L = np.empty((6, 6))
    # float arrays from np.empty, filled here: np.zeros and integer arrays are numba overloads
    # that a first call compiles apart from the kernel
    fac = np.empty(1)  # 1.0 when L holds a Cholesky factor
    fac[0] = 0.0
    zero = np.empty(3)
    sp = np.empty(m)
    x0 = np.empty(6)  # the previous station's strains and slope
    d0 = np.empty(6)
    xa = np.empty(6)  # the station before that, for the predictor
    da = np.empty(6)
    x1 = np.empty(6)  # this station's strains (at the base: the straight rod) and slope
    for a in range(6):
        x1[a] = 0.0
        if a < 3:
            zero[a] = 0.0
    x1[2] = 1.0
    d1 = np.empty(6)
    xm = np.empty(6)
    for a in range(3):
        p_out[0, a] = 0.0
        for b in range(3):
            R_out[0, a, b] = 1.0 if a == b else 0.0
    for i in range(m):
        lengths[i] = 0.0
    for k in range(n_steps + 1):
        j = 2 * k
        for a in range(6):
            if k == 1:
                x1[a] = x0[a] + h * d0[a]
            elif k > 1:
                x1[a] = 5.0 * xa[a] + 2.0 * h * da[a] - 4.0 * x0[a] + 4.0 * h * d0[a]
        if (
            local_strains_chord(
                x1, tau, rt_all[j], drt_all[j], zero, zero, kse, kbt, tol, maxit, F, L, fac
            )
            < 0
        ):
            return LOCAL_FAIL
        local_jacobian(x1, tau, rt_all[j], drt_all[j], kse, kbt, L)
        if not chol_factor6(L):
            return LOCAL_FAIL
        fac[0] = 1.0
        strain_slope(x1, tau, rt_all[j], drt_all[j], ddrt_all[j], L, d1)
        if k > 0:
            for a in range(6):
                xm[a] = 0.5 * (x0[a] + x1[a]) + 0.125 * h * (d0[a] - d1[a])
        # Simpson weights 1, 4, 2, 4, ..., 4, 1 over the nodes: the half step before this
        # station (weight 4), then the station itself
        for q in range(0 if k > 0 else 1, 2):
            xq = xm if q == 0 else x1
            wq = 4.0 if q == 0 else (1.0 if k == 0 or k == n_steps else 2.0)
            tendon_speeds(xq, rt_all[j - 1 + q], drt_all[j - 1 + q], sp)
            for i in range(m):
                lengths[i] += wq * sp[i]
        if k > 0:
            rk4_pose_step(p_out[k - 1], R_out[k - 1], x0, xm, x1, h, p_out[k], R_out[k])
        for a in range(6):
            x_out[k, a] = x1[a]
            xa[a] = x0[a]
            da[a] = d0[a]
            x0[a] = x1[a]
            d0[a] = d1[a]
    for i in range(m):
        lengths[i] *= h / 6.0
    return OK


@njit(cache=True)
def shape_free_batch(
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
    p_out,
    R_out,
    lengths_out,
    status,
):
    """Batched :func:`shape_free`: ``taus (B, m)`` -> ``p_out (B, n+1, 3)``, ``R_out (B, n+1, 3, 3)``."""
    B = taus.shape[0]
    x_out = np.empty((n_steps + 1, 6))
    for b in range(B):
        status[b] = shape_free(
            taus[b],
            rt_all,
            drt_all,
            ddrt_all,
            kse,
            kbt,
            length,
            n_steps,
            tol,
            maxit,
            p_out[b],
            R_out[b],
            x_out,
            lengths_out[b],
        )


@njit(cache=True)
def loaded_derivative(y, node, tau, rod, f, x, tol, maxit, work, dy):
    """Right-hand side of (1) with the strains from (2)-(3); ``y = (p, R (row-major), N, M, l)``.

    ``x`` is the warm start and receives the strains; ``work = (F (6,), J (6, 6), rhs (6, 1),
    sp (m,))`` is scratch space. Returns False if the local solve failed.
    """
    F, J, rhs, sp = work
    kse = rod.kse
    kbt = rod.kbt
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
    rt = rod.offsets[node]
    drt = rod.offset_slopes[node]
    if local_strains(x, tau, rt, drt, nb, mb, kse, kbt, tol, maxit, F, J, rhs) < 0:
        return False
    pose_derivative(R, x, dR, dp)
    for a in range(3):
        dy[a] = dp[a]
        for b in range(3):
            dy[3 + 3 * a + b] = dR[a, b]
        dy[12 + a] = -f[a]
    dy[15] = -(dp[1] * N2 - dp[2] * N1)
    dy[16] = -(dp[2] * N0 - dp[0] * N2)
    dy[17] = -(dp[0] * N1 - dp[1] * N0)
    tendon_speeds(x, rt, drt, sp)
    for i in range(m):
        dy[18 + i] = sp[i]
    return True


@njit(cache=True)
def shape_loaded(
    tau, rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps, f, N0, M0, tol, maxit, Y
):
    """Integrate (1)-(3) from base values ``N0, M0`` with distributed force ``f (3,)`` (base frame).

    ``Y (n+1, 18+m)`` receives the states ``(p, R row-major, N, M, l)``. Returns a status code.
    """
    rod = RodTables(rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps)
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
    work = (F, J, rhs, sp)
    for a in range(ny):
        Y[0, a] = 0.0
    Y[0, 3] = 1.0
    Y[0, 7] = 1.0
    Y[0, 11] = 1.0
    for a in range(3):
        Y[0, 12 + a] = N0[a]
        Y[0, 15 + a] = M0[a]
    for k in range(n_steps):
        y = Y[k]
        if not loaded_derivative(y, 2 * k, tau, rod, f, x, tol, maxit, work, k1):
            return LOCAL_FAIL
        for a in range(ny):
            ys[a] = y[a] + 0.5 * h * k1[a]
        if not loaded_derivative(ys, 2 * k + 1, tau, rod, f, x, tol, maxit, work, k2):
            return LOCAL_FAIL
        for a in range(ny):
            ys[a] = y[a] + 0.5 * h * k2[a]
        if not loaded_derivative(ys, 2 * k + 1, tau, rod, f, x, tol, maxit, work, k3):
            return LOCAL_FAIL
        for a in range(ny):
            ys[a] = y[a] + h * k3[a]
        if not loaded_derivative(ys, 2 * k + 2, tau, rod, f, x, tol, maxit, work, k4):
            return LOCAL_FAIL
        for a in range(ny):
            Y[k + 1, a] = y[a] + h / 6.0 * (k1[a] + 2.0 * k2[a] + 2.0 * k3[a] + k4[a])
    return OK
