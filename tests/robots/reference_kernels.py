"""Reference variants of the Cosserat kernels, for tests only: the shape pass that solves the
strain equations at the half steps too (instead of the Hermite midpoints of
``integration.shape_free``), and strains along arbitrary arc lengths."""

from __future__ import annotations

import numpy as np
from numba import njit

from riskplan.robots.integration import rk4_pose_step
from riskplan.robots.rod_tables import LOCAL_FAIL, OK, tendon_offsets
from riskplan.robots.strains import local_strains, local_strains_chord, tendon_speeds


@njit(cache=False)
def predict(xa, xb, xc, nhist, out):
    """Warm start for the next node: polynomial extrapolation from the last 1-3 node solutions."""
    for a in range(6):
        if nhist >= 3:
            out[a] = 3.0 * xa[a] - 3.0 * xb[a] + xc[a]
        elif nhist == 2:
            out[a] = 2.0 * xa[a] - xb[a]
        else:
            out[a] = xa[a]


@njit(cache=False)
def shape_free_exact_midpoints(
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
    tendon_speeds(x0, rt, drt, sp)
    for i in range(m):
        lengths[i] += sp[i]
    xb = x0.copy()  # node solutions two and three half-steps back, for the predictor
    xc = x0.copy()
    nhist = 1
    for k in range(n_steps):
        predict(x0, xb, xc, nhist, xm)
        rt = rt_all[2 * k + 1]
        drt = drt_all[2 * k + 1]
        if local_strains_chord(xm, tau, rt, drt, zero, zero, kse, kbt, tol, maxit, F, J, fac) < 0:
            return LOCAL_FAIL
        tendon_speeds(xm, rt, drt, sp)
        for i in range(m):
            lengths[i] += 4.0 * sp[i]
        nhist = min(nhist + 1, 3)
        predict(xm, x0, xb, nhist, x1)
        rt = rt_all[2 * k + 2]
        drt = drt_all[2 * k + 2]
        if local_strains_chord(x1, tau, rt, drt, zero, zero, kse, kbt, tol, maxit, F, J, fac) < 0:
            return LOCAL_FAIL
        tendon_speeds(x1, rt, drt, sp)
        w = 2.0 if k < n_steps - 1 else 1.0
        for i in range(m):
            lengths[i] += w * sp[i]
        rk4_pose_step(p_out[k], R_out[k], x0, xm, x1, h, p_out[k + 1], R_out[k + 1])
        nhist = min(nhist + 1, 3)
        for a in range(6):
            x_out[k + 1, a] = x1[a]
            xc[a] = x0[a]
            xb[a] = xm[a]
            x0[a] = x1[a]
    for i in range(m):
        lengths[i] *= h / 6.0
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
