"""Tensions for tendon displacements: the complementarity problem of compliant tendons that
may go slack (semismooth Newton with a Levenberg-Marquardt fallback and a line search),
without external loads.

The entry points called from Python (:func:`solve_displacement_tensions`,
:func:`solve_displacement_batch`) take the seven :class:`~riskplan.robots.rod_tables.RodTables`
fields as separate arrays, like those of :mod:`riskplan.robots.integration`: plain arrays cross
the Python boundary ten times faster than a named tuple, so these parameter lists repeat by
design; inside compiled code the tables travel as one ``RodTables``.

The helpers of :func:`solve_displacement_tensions` (system, search direction, line search,
Gaussian elimination) are compiled inline into it: numba links a called kernel's whole
machine-code module into each caller and optimises it again there, so a tower of separately
compiled helpers, each linking the length pass, made a first call optimise that pass four
times. Inline, they are typed once per call site (one each; ``_system_at``, three calls of two
calls, three), and the solve links only :func:`~riskplan.robots.tendon_lengths.lengths_and_jacobian`
and ``complementarity_system``. ``error_model="numpy"``: a division by zero gives inf or NaN
(caught by the residual and status checks) instead of a Python exception branch per division.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from riskplan.robots.integration import pose_from_node_strains
from riskplan.robots.linalg6 import gauss_solve
from riskplan.robots.rod_tables import LOCAL_FAIL, OK, OUTER_FAIL, RodTables
from riskplan.robots.tendon_lengths import lengths_and_jacobian

# step halvings of the displacement solve's line search (2**-30 ~ 1e-9 of a Newton step)
LINE_SEARCH_MAXIT = 30


@njit(cache=True, error_model="numpy")
def complementarity_system(d, kinv, l0, tau, lengths, dl, Jm, phi, fb, slack):
    """Newton system ``Jm step = phi`` of the complementarity problem at ``tau`` (see
    :func:`solve_displacement_tensions`) in length units, with ``a_i = tau_i * 1e-3`` (tensions in
    N compare with lengths in m at 1 mm/N) and ``b_i = g_i``: the min function
    ``r_i = min(a_i, b_i)`` (``fb = False``) or the Fischer-Burmeister function
    ``r_i = a_i + b_i - sqrt(a_i^2 + b_i^2)`` (``fb = True``, whose squared norm is smooth);
    ``phi = -r``, except that slack rows of the min function (``slack[i] = 1.0``) are written in
    tension units, ``step_i = -tau_i``. Returns ``(max |min(a_i, b_i)|, sum r_i^2)``."""
    m = d.shape[0]
    res = 0.0
    merit = 0.0
    for i in range(m):
        g = l0[i] - lengths[i] + tau[i] * kinv[i] - d[i]
        a = tau[i] * 1e-3
        # res = max(res, |min(a, g)|) written out (numba's min/max of a tuple is an overload a
        # first call compiles on its own; these are the comparisons they make, in their order)
        v = abs(g if g < a else a)
        if v > res:
            res = v
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
            slack[i] = 0.0
        elif tau[i] <= g:  # slack row kept in N (identity) so that a full step gives exactly 0
            for j in range(m):
                Jm[i, j] = 0.0
            Jm[i, i] = 1.0
            r = a
            phi[i, 0] = -tau[i]
            slack[i] = 1.0
        else:
            for j in range(m):
                Jm[i, j] = -dl[i, j]
            Jm[i, i] += kinv[i]
            r = g
            phi[i, 0] = -r
            slack[i] = 0.0
        merit += r * r
    return res, merit


@njit(cache=True, error_model="numpy", inline="always")
def levenberg_marquardt_system(Jm, phi, mu, A, b, m, slack):
    """``A = J^T J + mu I``, ``b = J^T phi`` (Levenberg-Marquardt normal equations) with the
    slack rows scaled to length units (1e-3 m/N) like the residual."""
    for i in range(m):
        acc = 0.0
        for k in range(m):
            w = 1e-6 if slack[k] != 0.0 else 1.0
            acc += w * Jm[k, i] * phi[k, 0]
        b[i, 0] = acc
        for j in range(m):
            acc = 0.0
            for k in range(m):
                w = 1e-6 if slack[k] != 0.0 else 1.0
                acc += w * Jm[k, i] * Jm[k, j]
            A[i, j] = acc
        A[i, i] += mu


@njit(cache=True, error_model="numpy", inline="always")
def search_direction(Jm, phi, merit, slack, lm, A, step, m):
    """Newton step (``lm`` False) or Levenberg-Marquardt step into ``step``; False if singular."""
    if lm:
        levenberg_marquardt_system(Jm, phi, merit, A, step, m, slack)
    else:
        for i in range(m):
            step[i, 0] = phi[i, 0]
            for j in range(m):
                A[i, j] = Jm[i, j]
    return gauss_solve(A, step, m, 1)


@njit(cache=True, error_model="numpy", inline="always")
def _system_at(d, kinv, l0, tau, rod, tol, maxit, lengths, dl, xs, Jm, phi, fb, slack):
    """Tendon lengths and their Jacobian at ``tau`` (:func:`lengths_and_jacobian`, which leaves
    the node strains in ``xs``), then the Newton system there (:func:`complementarity_system`);
    returns ``(status, residual, merit)`` (residual and merit 0 when the length solve failed)."""
    st = lengths_and_jacobian(
        tau, rod.offsets, rod.offset_slopes, rod.offset_curvatures, rod.kse, rod.kbt, rod.length, rod.n_steps,
        tol, maxit, lengths, dl, xs,
    )  # fmt: skip
    if st != OK:
        return st, 0.0, 0.0
    res, merit = complementarity_system(d, kinv, l0, tau, lengths, dl, Jm, phi, fb, slack)
    return OK, res, merit


@njit(cache=True, error_model="numpy", inline="always")
def line_search(d, kinv, l0, tau, step, merit, fb, rod, tols, work):
    """Backtracking on the squared residual along ``step`` from ``tau`` (projected on tau >= 0):
    halves the step until it falls by the Armijo factor. Leaves the accepted point in ``trial``
    with its system in ``Jt, pt, slack_t``; returns ``(accepted, max residual, merit)``.
    ``tols = (tol, maxit, dtol)``; ``work = (trial, lengths, dl, xs, Jt, pt, slack_t)``."""
    tol, maxit, dtol = tols
    trial, lengths, dl, xs, Jt, pt, slack_t = work
    m = tau.shape[0]
    alpha = 1.0
    for _ls in range(LINE_SEARCH_MAXIT):
        for i in range(m):
            t = tau[i] + alpha * step[i, 0]
            trial[i] = 0.0 if 0.0 > t else t  # max(t, 0.0), as numba's max compares
        st, res_t, merit_t = _system_at(
            d, kinv, l0, trial, rod, tol, maxit, lengths, dl, xs, Jt, pt, fb, slack_t
        )
        if st == OK and (merit_t <= (1.0 - 1e-4 * alpha) * merit or res_t <= dtol):
            return True, res_t, merit_t
        alpha *= 0.5
    return False, 0.0, 0.0


@njit(cache=True, error_model="numpy")
def solve_displacement_tensions(
    d,
    kinv,
    l0,
    tau0,
    rt_all,
    drt_all,
    ddrt_all,
    kse,
    kbt,
    length,
    n_steps,
    tol,
    maxit,
    dtol,
    outer_maxit,
    tau,
    info,
    xs,
):
    """Tensions for tendon displacements ``d (m,)`` with compliant tendons and slack (no loads),
    and the shape they hold.

    Complementarity (per tendon)::

        g_i(tau) = l0_i - l_i(tau) + tau_i * kinv_i - d_i,   tau_i >= 0, g_i >= 0, tau_i g_i = 0

    (pulling the actuator in by ``d_i`` shortens the tendon's rest length by ``d_i``; a taut
    tendon stretches by ``tau_i / k_i``). Semismooth Newton on ``min(tau, g) = 0`` with the
    analytic Jacobian of :func:`lengths_and_jacobian`, projected onto ``tau >= 0``, and a
    backtracking line search on the squared residual (steps are halved until it falls; the
    full step is taken whenever it does, so the local convergence stays quadratic). Needed for
    stiff problems such as inextensible antagonistic tendons, where full steps overshoot.
    ``tau0`` is the start. Writes ``tau``; ``info = [iterations, residual]``. Returns status.

    On success ``xs (2n+1, 6)`` holds the strains solved at every RK4 node at the returned
    ``tau``: the last length pass is always at it (the start when it already solves the
    problem, an accepted line-search point, or the re-evaluation at ``tau`` on the switch to
    Fischer-Burmeister), so :func:`~riskplan.robots.integration.pose_from_node_strains` gives
    the shape from them without another pass. The pose is a kernel of its own, called after
    this one: integrated here, its RK4 steps would be optimised again inside this kernel's
    module (about 1 s more to a first call than the separate kernel, measured).
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
    # slack flags (1.0: the row is slack) as float arrays from np.empty: np.zeros and integer
    # arrays are numba overloads that a first call compiles apart from the kernel
    slack = np.empty(m)
    slack_t = np.empty(m)
    rod = RodTables(rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps)
    tols = (tol, maxit, dtol)
    work = (trial, lengths, dl, xs, Jt, pt, slack_t)
    for i in range(m):
        tau[i] = tau0[i]
        slack[i] = 0.0
        slack_t[i] = 0.0
    info[0] = 0
    info[1] = 1e300
    # False, typed as a plain bool: a literal False (and later True) would compile each helper
    # that takes it once per literal value
    fb = m < 0
    st, res, merit = _system_at(
        d, kinv, l0, tau, rod, tol, maxit, lengths, dl, xs, Jm, phi, fb, slack
    )
    if st != OK:
        return st
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
            if search_direction(Jm, phi, merit, slack, attempt == 1, Jc, step, m):
                accepted, res_t, merit_t = line_search(
                    d, kinv, l0, tau, step, merit, fb, rod, tols, work
                )
                if accepted:
                    break
        if not accepted:
            if fb:
                return OUTER_FAIL
            # stuck at a stationary point of the min-function merit that is not a solution
            # (it is not smooth): continue with the Fischer-Burmeister form, whose merit has
            # no such points when dg/dtau is positive semidefinite, as a compliance matrix is
            fb = not fb  # True, typed as a plain bool (see above)
            st, res, merit = _system_at(
                d, kinv, l0, tau, rod, tol, maxit, lengths, dl, xs, Jm, phi, fb, slack
            )
            if st != OK:
                return LOCAL_FAIL
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
def solve_displacement_batch(
    ds,
    kinv,
    l0,
    tau0s,
    rt_all,
    drt_all,
    ddrt_all,
    kse,
    kbt,
    length,
    n_steps,
    tol,
    maxit,
    dtol,
    outer_maxit,
    taus,
    infos,
    status,
    p_out,
    R_out,
):
    """Batched :func:`solve_displacement_tensions` over ``ds (B, m)``, with the shapes
    ``p_out (B, n+1, 3)``, ``R_out (B, n+1, 3, 3)`` integrated from each solve's node strains
    (:func:`~riskplan.robots.integration.pose_from_node_strains`, the scalar path's kernel);
    a configuration that fails from its start ``tau0s[b]`` is tried once more from the slack
    state (``infos`` of the last try)."""
    slack_start = np.zeros(ds.shape[1])
    xs = np.empty((2 * n_steps + 1, 6))
    for b in range(ds.shape[0]):
        st = OUTER_FAIL
        for attempt in range(2):
            start = tau0s[b] if attempt == 0 else slack_start
            st = solve_displacement_tensions(
                ds[b], kinv, l0, start, rt_all, drt_all, ddrt_all, kse, kbt, length, n_steps,
                tol, maxit, dtol, outer_maxit, taus[b], infos[b], xs,
            )  # fmt: skip
            if st == OK:
                pose_from_node_strains(xs, length / n_steps, n_steps, p_out[b], R_out[b])
                break
        status[b] = st
