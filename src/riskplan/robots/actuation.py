"""The solves behind a :class:`~riskplan.robots.TendonRobot`'s methods, on flat batches: the
shapes at given tensions (which kernel for which batch), the tensions that realise tendon
displacements (the complementarity problem of
:func:`riskplan.robots.cosserat.solve_displacement_tensions`: start values, the scalar or
batched kernel, a retry from the slack state), the tendons' path lengths, and the error that
names where a failed local strain solve stops. Each takes the robot first and flat, checked
arrays ``(B, m)``; the facade's methods check inputs and restore batch shapes.
"""

from __future__ import annotations

import math

import numpy as np

from riskplan.errors import ConvergenceError
from riskplan.robots import cosserat
from riskplan.robots import loaded as _loaded
from riskplan.robots.rod_tables import DISP_MAXIT, DISP_TOL, LOCAL_MAXIT, LOCAL_TOL

__all__ = [
    "BATCH_KERNEL_MIN",
    "local_failure_error",
    "shapes_for_displacements",
    "solve_batch",
    "solve_single_free",
    "tendon_lengths",
    "tensions_for_displacements",
]

# Batches at least this large use the configuration-vectorised kernel (faster from ~8 on).
BATCH_KERNEL_MIN = 8


def tensions_for_displacements(robot, flat: np.ndarray) -> np.ndarray:
    """Tensions ``(B, m)`` [N] that realise the displacements ``flat (B, m)`` [m].

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    flat : numpy.ndarray
        ``(B, m)`` tendon displacements [m].

    Returns
    -------
    numpy.ndarray
        ``(B, m)`` tensions [N].
    """
    B, m = flat.shape
    if robot.loaded:
        return (
            np.stack([_loaded.tensions_loaded(robot, flat[b]) for b in range(B)])
            if B
            else np.zeros((0, m))
        )
    return _solve_free_displacements(robot, flat, shapes=False)[0]


def shapes_for_displacements(robot, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tensions ``(B, m)`` [N] that realise the displacements ``flat (B, m)`` [m] of a robot
    without external loads, and the shapes they hold: positions ``(B, n, 3)`` [m] and frames
    ``(B, n, 3, 3)``, base frame, integrated from the strains of the solve's last length pass
    (:func:`cosserat.solve_displacement_tensions`), so no shape kernel runs.

    Parameters
    ----------
    robot : TendonRobot
        A robot without external loads.
    flat : numpy.ndarray
        ``(B, m)`` tendon displacements [m].

    Returns
    -------
    tau : numpy.ndarray
        ``(B, m)`` tensions [N].
    positions : numpy.ndarray
        ``(B, n, 3)`` [m], base frame.
    frames : numpy.ndarray
        ``(B, n, 3, 3)``, base frame.
    """
    tau, P, Rs = _solve_free_displacements(robot, flat)
    if not np.isfinite(P).all():  # never hand out NaN silently
        b = int(np.flatnonzero(~np.isfinite(P).reshape(P.shape[0], -1).all(-1))[0])
        raise ConvergenceError(f"non-finite shape for displacements {flat[b].tolist()}")
    return tau, P, Rs


def _solve_free_displacements(robot, flat: np.ndarray, shapes: bool = True):
    """``(tau, P, Rs)`` of :func:`shapes_for_displacements` (unchecked shapes; with
    ``shapes=False`` a single configuration's pose is not integrated, a batch's always is, in
    the batch kernel); raises :class:`ConvergenceError` where a tension solve fails."""
    B, m = flat.shape
    n = robot._n + 1
    # start: the linearisation at tau = 0 (see TendonRobot.__init__), clipped to tau >= 0
    tau0 = np.ascontiguousarray(np.maximum(flat @ robot._A0pinv.T, 0.0))
    tau = np.empty((B, m))
    infos = np.empty((B, 2))
    status = np.empty(B, dtype=np.int64)
    P = np.empty((B, n, 3))
    Rs = np.empty((B, n, 3, 3))
    xs = None
    if B == 1:
        # one configuration: the scalar kernel, so that a first call compiles no batch loop;
        # the pose below
        xs = np.empty((2 * n - 1, 6))
        status[0] = _displacement_tensions(robot, flat[0], tau0[0], tau[0], infos[0], xs)
    else:  # the batch kernel integrates each pose itself (one call, no loop here)
        cosserat.solve_displacement_batch(
            flat,
            robot._kinv,
            robot._l0,
            tau0,
            *robot.tables,
            LOCAL_TOL,
            LOCAL_MAXIT,
            DISP_TOL,
            DISP_MAXIT,
            tau,
            infos,
            status,
            P,
            Rs,
        )
    bad = np.flatnonzero(status != cosserat.OK)
    if bad.size:
        b = int(bad[0])
        raise ConvergenceError(
            f"tension solve for displacements {flat[b].tolist()} did not converge (residual {infos[b, 1]:.3g} m)",
            residual=float(infos[b, 1]),
            iterations=int(infos[b, 0]),
        )
    if xs is not None and shapes:
        cosserat.pose_from_node_strains(xs, robot._L / robot._n, robot._n, P[0], Rs[0])
    return tau, P, Rs


def _displacement_tensions(robot, d, tau0, tau, info, xs) -> int:
    """:func:`cosserat.solve_displacement_tensions` for one configuration (node strains into ``xs``),
    tried once more from the slack state when it fails from ``tau0`` (as
    :func:`cosserat.solve_displacement_batch` does per configuration); returns the status."""
    st = cosserat.OUTER_FAIL
    for start in (tau0, np.zeros(robot.n_tendons)):
        st = cosserat.solve_displacement_tensions(
            d, robot._kinv, robot._l0, start, *robot.tables, LOCAL_TOL, LOCAL_MAXIT, DISP_TOL,
            DISP_MAXIT, tau, info, xs,
        )  # fmt: skip
        if st == cosserat.OK:
            break
    return st


def tendon_lengths(robot, flat: np.ndarray) -> np.ndarray:
    """Tendon path lengths ``(B, m)`` [m] at the tensions ``flat (B, m)`` [N].

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    flat : numpy.ndarray
        ``(B, m)`` tensions [N].

    Returns
    -------
    numpy.ndarray
        ``(B, m)`` tendon path lengths [m].
    """
    m = robot.n_tendons
    out = np.empty(flat.shape)
    for b in range(flat.shape[0]):
        if robot.loaded:
            out[b] = robot._shoot(flat[b])[-1, 18:]
        else:
            dl, xs = np.empty((m, m)), np.empty((2 * robot._n + 1, 6))
            if (
                cosserat.lengths_and_jacobian(
                    flat[b], *robot.tables, LOCAL_TOL, LOCAL_MAXIT, out[b], dl, xs
                )
                != cosserat.OK
            ):
                raise local_failure_error(robot, flat[b])
    return out


def local_failure_error(robot, tau) -> ConvergenceError:
    """The error for a failed local strain solve (eqs. 2-3) of the unloaded rod at tensions
    ``tau (m,)``, naming the first node where a plain Newton re-solve stops and its scaled
    residual ``max |F_a / K_aa|``.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    tau : array_like, shape (m,)
        The tensions [N] whose solve failed.

    Returns
    -------
    ConvergenceError
        The error to raise.
    """
    tau = np.ascontiguousarray(tau, dtype=np.float64)
    F, J, rhs, zero = np.empty(6), np.empty((6, 6)), np.empty((6, 1)), np.zeros(3)
    x = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    kse, kbt = robot.tables.kse, robot.tables.kbt
    for k in range(robot._n + 1):
        rt, drt = robot.tables.offsets[2 * k], robot.tables.offset_slopes[2 * k]
        if (
            cosserat.local_strains(
                x, tau, rt, drt, zero, zero, kse, kbt, LOCAL_TOL, LOCAL_MAXIT, F, J, rhs
            )
            < 0
        ):
            res = float(cosserat.local_residual(x, tau, rt, drt, zero, zero, kse, kbt, F))
            return ConvergenceError(
                f"local strain solve failed at s = {robot._s[k]:.4g} m for tensions {tau.tolist()} "
                f"(scaled residual {res:.3g} after {LOCAL_MAXIT} Newton iterations, tolerance {LOCAL_TOL:g})",
                residual=res,
                iterations=LOCAL_MAXIT,
            )
    return ConvergenceError(
        f"local strain solve failed for tensions {tau.tolist()} (a plain Newton re-solve converges)"
    )


def solve_single_free(robot, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One configuration ``tau (m,)`` [N] without external loads: the scalar kernel, no batch
    bookkeeping; positions ``(n, 3)`` [m] and frames ``(n, 3, 3)``, base frame.

    Parameters
    ----------
    robot : TendonRobot
        A robot without external loads.
    tau : numpy.ndarray
        ``(m,)`` tensions [N].

    Returns
    -------
    positions : numpy.ndarray
        ``(n, 3)`` [m], base frame.
    frames : numpy.ndarray
        ``(n, 3, 3)``, base frame.
    """
    n, m = robot._n + 1, robot.n_tendons
    P = np.empty((n, 3))
    Rs = np.empty((n, 3, 3))
    st = cosserat.shape_free(
        tau, *robot.tables, LOCAL_TOL, LOCAL_MAXIT, P, Rs, np.empty((n, 6)), np.empty(m)
    )
    if st != cosserat.OK:
        raise local_failure_error(robot, tau)
    # a non-finite value anywhere propagates along the RK4 pass to the tip position
    if not math.isfinite(P[-1, 0] + P[-1, 1] + P[-1, 2]):
        raise ConvergenceError(f"non-finite shape for tensions {tau.tolist()}")
    return P, Rs


def solve_batch(robot, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shapes at the tensions ``flat (B, m)`` [N]: positions ``(B, n, 3)`` [m] and frames
    ``(B, n, 3, 3)``, base frame. Without gravity batches of ``BATCH_KERNEL_MIN`` or more go
    through the SIMD kernel (:mod:`riskplan.robots.batch_kernel`, the same results), one
    configuration through the scalar kernel, others through the batched loop; with gravity,
    shooting per configuration.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    flat : numpy.ndarray
        ``(B, m)`` tensions [N].

    Returns
    -------
    positions : numpy.ndarray
        ``(B, n, 3)`` [m], base frame.
    frames : numpy.ndarray
        ``(B, n, 3, 3)``, base frame.
    """
    B, n, m = flat.shape[0], robot._n + 1, robot.n_tendons
    P = np.empty((B, n, 3))
    Rs = np.empty((B, n, 3, 3))
    if not robot.loaded and B >= BATCH_KERNEL_MIN:
        # Same algorithm, vectorised across configurations (bit-identical results).
        from riskplan.robots.batch_kernel import solve_tensions_batch

        P, Rs = solve_tensions_batch(robot, flat, parallel=False, validate=False)
    elif not robot.loaded and B == 1:
        # one configuration given as a batch: the scalar kernel (no batch loop to compile)
        st = cosserat.shape_free(
            flat[0], *robot.tables, LOCAL_TOL, LOCAL_MAXIT, P[0], Rs[0], np.empty((n, 6)),
            np.empty(m),
        )  # fmt: skip
        if st != cosserat.OK:
            raise local_failure_error(robot, flat[0])
    elif not robot.loaded:
        lengths = np.empty((B, m))
        status = np.empty(B, dtype=np.int64)
        cosserat.shape_free_batch(
            flat, *robot.tables, LOCAL_TOL, LOCAL_MAXIT, P, Rs, lengths, status
        )
        bad = np.flatnonzero(status != cosserat.OK)
        if bad.size:
            raise local_failure_error(robot, flat[bad[0]])
    else:
        for b in range(B):
            Y = robot._shoot(flat[b])
            P[b] = Y[:, 0:3]
            Rs[b] = Y[:, 3:12].reshape(n, 3, 3)
    if not np.isfinite(P).all():  # never hand out NaN silently
        b = int(np.flatnonzero(~np.isfinite(P).reshape(B, -1).all(-1))[0])
        raise ConvergenceError(f"non-finite shape for tensions {flat[b].tolist()}")
    return P, Rs
