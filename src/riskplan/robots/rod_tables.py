"""Per-robot arrays of the Cosserat kernels, in one named container, and the kernels'
status codes.

:class:`RodTables` holds what depends only on the robot description: the body-frame tendon
offsets ``r_i(s)`` and their first and second derivatives at the ``2 n + 1`` RK4 nodes (steps
and half steps), the stiffness diagonals ``K_se``, ``K_bt`` (Rucker & Webster 2011, eqs. 2-4),
the rod length and the number of RK4 steps. ``TendonRobot.tables`` builds it once. Kernels
called from Python take its seven fields in order (``shape_free(tau, *robot.tables, ...)``):
numba types a named tuple argument in Python, about 10 us per call against about 1 us for
plain arrays, which the single-configuration solve would feel. Inside compiled code the kernels
rebuild it and hand it on as one argument (``RodTables(...)`` costs nothing there).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

# the local strain solve's Newton tolerance (strain units: 1 and 1/m) and iteration cap, shared by
# the scalar and the batch kernels' callers
LOCAL_TOL = 1e-10
LOCAL_MAXIT = 50
# the displacement -> tension solve's complementarity residual [m] and iteration cap
DISP_TOL = 1e-12
DISP_MAXIT = 60

# status codes returned by the kernels
OK = 0
LOCAL_FAIL = 1
OUTER_FAIL = 2


class RodTables(NamedTuple):
    """Per-robot arrays of the kernels (``n`` RK4 steps, ``m`` tendons).

    offsets: ``(2n+1, m, 3)`` tendon offsets ``r_i`` at the RK4 nodes (body frame);
    offset_slopes: ``(2n+1, m, 3)`` ``r_i'``; offset_curvatures: ``(2n+1, m, 3)`` ``r_i''``;
    kse, kbt: ``(3,)`` shear/extension and bending/torsion stiffness diagonals;
    length: rod length [m]; n_steps: RK4 steps.
    """

    offsets: np.ndarray
    offset_slopes: np.ndarray
    offset_curvatures: np.ndarray
    kse: np.ndarray
    kbt: np.ndarray
    length: float
    n_steps: int


@njit(cache=True)
def polyval(c, s):
    out = 0.0
    for k in range(c.shape[0] - 1, -1, -1):
        out = out * s + c[k]
    return out


@njit(cache=True)
def dpolyval(c, s):
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
        th = polyval(theta_c[i], s)
        dth = dpolyval(theta_c[i], s)
        r = polyval(radius_c[i], s)
        dr = dpolyval(radius_c[i], s)
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
    three arrays ``(2n+1, m, 3)``.

    The operations of :func:`tendon_offsets` in the same order (Horner's rule, ``math.cos`` and
    ``math.sin``), vectorised over the nodes with numpy instead of compiled, so that building a
    robot compiles nothing (and takes a third of the time of 2n+1 kernel calls).

    Parameters
    ----------
    theta_c : numpy.ndarray
        ``(m, Kt)`` routing-angle polynomials [rad] (ascending powers of s).
    radius_c : numpy.ndarray
        ``(m, Kr)`` routing-radius polynomials [m].
    length : float
        Backbone length [m].
    n_steps : int
        RK4 steps ``n``.

    Returns
    -------
    tuple of numpy.ndarray
        ``r_i``, ``r_i'``, ``r_i''``, each ``(2n + 1, m, 3)``.
    """
    n_nodes = 2 * n_steps + 1
    m = theta_c.shape[0]
    rt_all = np.zeros((n_nodes, m, 3))
    drt_all = np.zeros((n_nodes, m, 3))
    ddrt_all = np.zeros((n_nodes, m, 3))
    h = length / n_steps
    P = np.polynomial.polynomial
    s = np.arange(n_nodes) * 0.5 * h
    for i in range(m):
        th = P.polyval(s, theta_c[i])
        d1 = P.polyval(s, P.polyder(theta_c[i])) if theta_c.shape[1] > 1 else 0 * s
        d2 = P.polyval(s, P.polyder(theta_c[i], 2)) if theta_c.shape[1] > 2 else 0 * s
        rho = P.polyval(s, radius_c[i])
        r1 = P.polyval(s, P.polyder(radius_c[i])) if radius_c.shape[1] > 1 else 0 * s
        r2 = P.polyval(s, P.polyder(radius_c[i], 2)) if radius_c.shape[1] > 2 else 0 * s
        # libm's cosine and sine, as the compiled kernel calls them (numpy's own may differ
        # in the last bit)
        c = np.array([math.cos(t) for t in th.tolist()])
        sn = np.array([math.sin(t) for t in th.tolist()])
        rt_all[:, i, 0] = rho * c
        rt_all[:, i, 1] = rho * sn
        drt_all[:, i, 0] = r1 * c - rho * d1 * sn
        drt_all[:, i, 1] = r1 * sn + rho * d1 * c
        ddrt_all[:, i, 0] = r2 * c - 2 * r1 * d1 * sn - rho * d2 * sn - rho * d1 * d1 * c
        ddrt_all[:, i, 1] = r2 * sn + 2 * r1 * d1 * c + rho * d2 * c - rho * d1 * d1 * sn
    return rt_all, drt_all, ddrt_all


def rod_tables(theta_c, radius_c, kse, kbt, length: float, n_steps: int) -> RodTables:
    """:class:`RodTables` from the routing polynomials ``theta_c (m, Kt)``, ``radius_c (m, Kr)``
    (ascending powers of s), the stiffness diagonals and the discretisation.

    Parameters
    ----------
    theta_c : numpy.ndarray
        ``(m, Kt)`` routing-angle polynomials [rad].
    radius_c : numpy.ndarray
        ``(m, Kr)`` routing-radius polynomials [m].
    kse, kbt : array_like, shape (3,)
        Shear-extension and bending-torsion stiffness diagonals.
    length : float
        Backbone length [m].
    n_steps : int
        RK4 steps.

    Returns
    -------
    RodTables
        The tables the kernels read.
    """
    rt, drt, ddrt = tendon_offset_table(theta_c, radius_c, length, n_steps)
    return RodTables(
        rt,
        drt,
        ddrt,
        np.ascontiguousarray(kse, dtype=np.float64),
        np.ascontiguousarray(kbt, dtype=np.float64),
        float(length),
        int(n_steps),
    )
