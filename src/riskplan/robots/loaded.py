"""Solves of a :class:`~riskplan.robots.TendonRobot` under gravity (external load).

The facade's shooting solve on the base moment (the loaded rod,
:func:`riskplan.robots.cosserat.shape_loaded`) and its tension solve for displacements with
gravity on (semismooth Newton with finite differences). Each takes the robot first.
"""

from __future__ import annotations

import numpy as np

from riskplan.errors import ConvergenceError
from riskplan.robots import cosserat
from riskplan.robots.rod_tables import DISP_MAXIT, LOCAL_MAXIT, LOCAL_TOL

__all__ = ["SHOOT_MAXIT", "SHOOT_TOL", "gravity_base", "shoot", "tensions_loaded"]

SHOOT_TOL = 1e-11  # N m, tip-moment residual of the shooting solve
SHOOT_MAXIT = 30


def gravity_base(robot) -> np.ndarray:
    """Distributed force per unit length in the base frame [N/m].

    Parameters
    ----------
    robot : TendonRobot
        The robot (its mass per length, base pose and gravity).

    Returns
    -------
    numpy.ndarray
        ``(3,)`` force per length ``λ Rᵀ g`` [N/m].
    """
    return robot._lam * (
        robot.params.base.matrix.T @ np.asarray(robot.params.gravity.vector, dtype=float)
    )


def shoot(robot, tau) -> np.ndarray:
    """States ``(n+1, 18+m)`` of the loaded rod: ``N(0) = f L`` exactly, ``M(0)`` by Newton.

    Parameters
    ----------
    robot : TendonRobot
        A robot with gravity on.
    tau : array_like, shape (m,)
        Tensions [N].

    Returns
    -------
    numpy.ndarray
        ``(n + 1, 18 + m)`` rod states per node, the tendon lengths [m] in the last ``m``
        columns.
    """
    m, n, L = robot.n_tendons, robot._n, robot._L
    f = gravity_base(robot)
    N0 = f * L
    Y = np.empty((n + 1, 18 + m))
    # start: base moment of the gravity load on the unloaded shape, M(0) = int p' x f (L - s) ds
    P = np.empty((n + 1, 3))
    Rs = np.empty((n + 1, 3, 3))
    X = np.empty((n + 1, 6))
    lengths = np.empty(m)
    if (
        cosserat.shape_free(tau, *robot.tables, LOCAL_TOL, LOCAL_MAXIT, P, Rs, X, lengths)
        != cosserat.OK
    ):
        raise robot.local_failure_error(tau)
    mid = 0.5 * (P[1:] + P[:-1])
    M0 = np.cross(mid - P[0], f).sum(0) * (L / n)
    scale = max(1e-6, float(np.linalg.norm(f)) * L * L)

    def residual(M):
        st = cosserat.shape_loaded(tau, *robot.tables, f, N0, M, LOCAL_TOL, LOCAL_MAXIT, Y)
        if st != cosserat.OK:
            raise ConvergenceError(
                f"local strain solve failed while shooting (tensions {tau.tolist()})"
            )
        return Y[-1, 15:18].copy()

    res = np.inf
    for _it in range(SHOOT_MAXIT):
        r = residual(M0)
        res = float(np.abs(r).max())
        if res <= SHOOT_TOL * max(1.0, scale * 1e3):
            return Y.copy()
        Jm = np.empty((3, 3))
        eps = 1e-6 * scale
        for j in range(3):
            Mp = M0.copy()
            Mp[j] += eps
            Jm[:, j] = (residual(Mp) - r) / eps
        M0 = M0 - np.linalg.solve(Jm, r)
    raise ConvergenceError(
        f"shooting did not converge in {SHOOT_MAXIT} iterations (tip moment residual {res:.3g} N m)",
        residual=res,
        iterations=SHOOT_MAXIT,
    )


def tensions_loaded(robot, d) -> np.ndarray:
    """Semismooth Newton on ``min(tau, g(tau)) = 0`` with finite differences (gravity on).

    Parameters
    ----------
    robot : TendonRobot
        A robot with gravity on.
    d : numpy.ndarray
        ``(m,)`` tendon displacements [m].

    Returns
    -------
    numpy.ndarray
        ``(m,)`` tensions [N] with ``tau >= 0`` and ``g(tau) = l0 − l(tau) + tau / k − d >= 0``,
        complementary.
    """
    m = robot.n_tendons
    tau = np.maximum(robot._A0pinv @ d, 0.0)

    def g(t):
        return robot._l0 - robot._shoot(t)[-1, 18:] + t * robot._kinv - d

    res = np.inf
    for _it in range(DISP_MAXIT):
        gv = g(tau)
        act = tau > gv
        phi = np.where(act, gv, tau)
        res = float(np.abs(np.where(act, gv, tau * 1e-3)).max())
        if res <= 1e-11:
            return tau
        Jm = np.eye(m)
        for j in range(m):
            eps = 1e-6 * max(1.0, tau[j])
            tp = tau.copy()
            tp[j] += eps
            col = (g(tp) - gv) / eps
            Jm[act, j] = col[act]
        tau = np.maximum(tau - np.linalg.solve(Jm, phi), 0.0)
    raise ConvergenceError(
        f"tension solve with gravity did not converge (residual {res:.3g} m)",
        residual=res,
        iterations=DISP_MAXIT,
    )
