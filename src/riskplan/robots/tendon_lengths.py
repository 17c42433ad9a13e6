"""Tendon path lengths ``l_i = int_0^L |w_i| ds`` and their sensitivity to the tensions
(the Jacobian the displacement solve needs), without external loads."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from riskplan.robots.linalg6 import chol_factor6, chol_solve6
from riskplan.robots.rod_tables import LOCAL_FAIL, OK
from riskplan.robots.strains import local_jacobian, local_strains_chord, row3, unit_tangent


@njit(cache=True, error_model="numpy")
def lengths_and_jacobian(
    tau, rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps, tol, maxit, lengths, dl, xs
):
    """Tendon path lengths ``l (m,)`` and ``dl[i, j] = d l_i / d tau_j`` without external loads.

    Uses Simpson's rule on the RK4 nodes; the sensitivity of the local strains is
    ``dx/dtau_j = -J^{-1} [t_j; r_j x t_j]`` (implicit function theorem on eqs. (2)-(3)) and
    ``d|w_i|/dx = [t_i; r_i x t_i]``. Returns a status code. Arguments 2-8: the fields of
    :class:`~riskplan.robots.rod_tables.RodTables` (``ddrt_all`` unused). ``xs (2n+1, 6)``
    receives the strains ``(v, u)`` solved at the nodes (steps and half steps), from which
    :func:`~riskplan.robots.integration.pose_from_node_strains` integrates the shape (rows
    past a failed node are left as they were).
    """
    m = tau.shape[0]
    h = length / n_steps
    n_nodes = 2 * n_steps + 1
    F = np.empty(6)
    J = np.empty((6, 6))
    # float arrays from np.empty, filled here: np.zeros and integer arrays are numba overloads
    # that a first call compiles apart from the kernel (a few tenths of a second each)
    fac = np.empty(1)  # 1.0 when J holds a Cholesky factor
    fac[0] = 0.0
    col = np.empty(6)
    S = np.empty((6, m))
    G = np.empty((6, m))
    zero = np.empty(3)
    x = np.empty(6)
    for a in range(6):
        x[a] = 0.0
        if a < 3:
            zero[a] = 0.0
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
        for a in range(6):
            xs[node, a] = x[a]
        local_jacobian(x, tau, rt, drt, kse, kbt, J)
        if not chol_factor6(J):
            return LOCAL_FAIL
        fac[0] = 1.0
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
            nw, t0, t1, t2 = unit_tangent(x, row3(rt, i), row3(drt, i))
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
            chol_solve6(J, col)
            for a in range(6):
                S[a, j] = col[a]
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for a in range(6):
                    acc += G[a, i] * S[a, j]
                dl[i, j] += wgt * acc
    return OK


def rest_lengths_and_jacobian(rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps):
    """:func:`lengths_and_jacobian` at zero tension, with numpy instead of compiled code.

    At ``tau = 0`` the rod is straight (``x = (0, 0, 1, 0, 0, 0)`` solves eqs. (2)-(3) at every
    node with no Newton step) and the local Jacobian is ``J = diag(K_se, K_bt)``, so the
    kernel's pass reduces to array operations over the nodes: ``l_i = sum_k w_k |w_i|`` and
    ``dl[i, j] = -sum_k w_k [t_i; r_i x t_i]^T J^{-1} [t_j; r_j x t_j]`` (Simpson weights
    ``w_k``). The operations are the kernel's, in its order (the Cholesky factor and solve of
    the diagonal ``J`` with their zero terms, the sums from 0.0 node after node), so the results
    are the kernel's to the bit; building a robot (which needs them for its rest lengths)
    then compiles nothing.

    Parameters
    ----------
    rt_all, drt_all, ddrt_all : ndarray, shape (2n+1, m, 3)
        The robot's tendon offsets and their derivatives at the RK4 nodes
        (:class:`~riskplan.robots.rod_tables.RodTables`; ``ddrt_all`` unused).
    kse, kbt : ndarray, shape (3,)
        Stiffness diagonals.
    length : float
        Rod length [m].
    n_steps : int
        RK4 steps.

    Returns
    -------
    lengths : ndarray, shape (m,)
        Tendon path lengths at rest [m].
    dl : ndarray, shape (m, m)
        ``d l_i / d tau_j`` at ``tau = 0`` [m/N].
    """
    rt = np.asarray(rt_all, dtype=np.float64)
    drt = np.asarray(drt_all, dtype=np.float64)
    n_nodes = 2 * n_steps + 1
    h = length / n_steps
    # the straight rod's strains, as the kernel's unit_tangent sees them: w = v + u x r + r'
    x = (0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    r0, r1, r2 = rt[..., 0], rt[..., 1], rt[..., 2]  # (n_nodes, m)
    w0 = x[0] + x[4] * r2 - x[5] * r1 + drt[..., 0]
    w1 = x[1] + x[5] * r0 - x[3] * r2 + drt[..., 1]
    w2 = x[2] + x[3] * r1 - x[4] * r0 + drt[..., 2]
    nw = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    t0, t1, t2 = w0 / nw, w1 / nw, w2 / nw
    G = np.stack([t0, t1, t2, r1 * t2 - r2 * t1, r2 * t0 - r0 * t2, r0 * t1 - r1 * t0], axis=1)
    # chol_factor6 of diag(K_se, K_bt): sqrt on the diagonal, zeros below it
    L = np.zeros((6, 6))
    for j, kj in enumerate((*kse, *kbt)):
        L[j, j] = math.sqrt(kj)
    # chol_solve6 on every column -G[:, :, j] at once (the zero products included)
    b = -G  # (n_nodes, 6, m)
    for i in range(6):
        acc = b[:, i]
        for k in range(i):
            acc = acc - L[i, k] * b[:, k]
        b[:, i] = acc / L[i, i]
    for i in range(5, -1, -1):
        acc = b[:, i]
        for k in range(i + 1, 6):
            acc = acc - L[k, i] * b[:, k]
        b[:, i] = acc / L[i, i]
    wgt = np.full(n_nodes, 2.0 * h / 6.0)
    wgt[1::2] = 4.0 * h / 6.0
    wgt[0] = wgt[-1] = h / 6.0
    acc = np.zeros(G.shape[:1] + (G.shape[2], G.shape[2]))
    for a in range(6):
        acc = acc + G[:, a, :, None] * b[:, a, None, :]
    m = rt.shape[1]
    lengths = np.zeros(m)
    dl = np.zeros((m, m))
    for node in range(n_nodes):  # node after node, as the kernel adds
        lengths = lengths + wgt[node] * nw[node]
        dl = dl + wgt[node] * acc[node]
    return lengths, dl
