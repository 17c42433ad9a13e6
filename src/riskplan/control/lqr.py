"""Finite-horizon, time-varying linear-quadratic regulator (deformable-planning paper
section IV-C; the backward Riccati recursion of e.g. Bertsekas, *Dynamic Programming and
Optimal Control*, vol. 1, ch. 4).

Deviation dynamics ``x_{t+1} = A_t x_t + B_t u_t`` for ``t = 0 .. T-1`` and the cost

    J = Σ_{t=0}^{T-1} (x_tᵀ Q x_t + u_tᵀ R u_t) + x_Tᵀ Q_final x_T.

Backward recursion, ``S_T = Q_final``, for ``t = T-1 .. 0``:

    L_t = -(B_tᵀ S_{t+1} B_t + R)⁻¹ B_tᵀ S_{t+1} A_t
    S_t = Q + A_tᵀ S_{t+1} (A_t + B_t L_t)

and the optimal feedback is ``u_t = L_t x_t`` (note the sign: python-control's ``dlqr``
returns ``K`` with ``u = -K x``; in the long-horizon limit of a time-invariant system
``L_0 → -K``).
"""

from __future__ import annotations

import numpy as np

from riskplan._validation import check_dynamics, check_psd, per_step, raise_overflow

__all__ = ["lqr_gains", "lqr_recursion"]


def lqr_recursion(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, Q_final: np.ndarray):
    """The recursion without checks: ``A (T, p, p)``, ``B (T, p, q)``, ``Q (T, p, p)``, ``R (T, q, q)``,
    ``Q_final (p, p)``; returns ``(L (T, q, p), S (T + 1, p, p))`` with ``S[t]`` the cost-to-go matrix.

    Parameters
    ----------
    A : numpy.ndarray
        ``(T, p, p)`` state matrices.
    B : numpy.ndarray
        ``(T, p, q)`` control matrices.
    Q : numpy.ndarray
        ``(T, p, p)`` state costs.
    R : numpy.ndarray
        ``(T, q, q)`` control costs.
    Q_final : numpy.ndarray
        ``(p, p)`` final state cost.

    Returns
    -------
    L : numpy.ndarray
        ``(T, q, p)`` feedback gains, ``u_t = L_t x_t`` (equations of :func:`lqr_gains`).
    S : numpy.ndarray
        ``(T + 1, p, p)`` cost-to-go matrices, ``S[T] = Q_final``.
    """
    T, p, q = B.shape
    L = np.empty((T, q, p))
    S = np.empty((T + 1, p, p))
    S[T] = Q_final
    for t in range(T - 1, -1, -1):
        St = S[t + 1]
        At, Bt = A[t], B[t]
        with np.errstate(over="ignore", invalid="ignore"):
            SB = St @ Bt
            try:
                L[t] = -np.linalg.solve(Bt.T @ SB + R[t], SB.T @ At)
            except np.linalg.LinAlgError as exc:  # a singular matrix after an overflow
                raise_overflow("LQR Riccati recursion", t, exc)
            Sn = Q[t] + At.T @ St @ (At + Bt @ L[t])
            S[t] = 0.5 * (Sn + Sn.T)
        if not (np.isfinite(L[t]).all() and np.isfinite(S[t]).all()):
            raise_overflow("LQR Riccati recursion", t)
    return L, S


def lqr_gains(A, B, Q, R, Q_final) -> np.ndarray:
    r"""Feedback gains of the finite-horizon LQR, ``u_t = L_t x_t`` (paper IV-C).

    With ``S_T = Q_final`` and, for ``t = T-1 .. 0``,

    .. math::

        L_t = -(B_t^\top S_{t+1} B_t + R)^{-1} B_t^\top S_{t+1} A_t, \qquad
        S_t = Q + A_t^\top S_{t+1} (A_t + B_t L_t),

    which minimise :math:`\sum_{t<T} (x_t^\top Q x_t + u_t^\top R u_t) + x_T^\top
    Q_{final} x_T` for :math:`x_{t+1} = A_t x_t + B_t u_t`.

    Parameters
    ----------
    A : array_like
        ``(T, p, p)`` state matrices, ``x_{t+1} = A_t x_t + B_t u_t``.
    B : array_like
        ``(T, p, q)`` control matrices.
    Q : array_like
        ``(p, p)`` or ``(T, p, p)`` state cost, symmetric positive semi-definite (weights
        ``x_0 .. x_{T-1}``).
    R : array_like
        ``(q, q)`` or ``(T, q, q)`` control cost, symmetric positive definite.
    Q_final : array_like
        ``(p, p)`` final state cost on ``x_T``, symmetric positive semi-definite.

    Returns
    -------
    numpy.ndarray
        ``L (T, q, p)``.

    Raises
    ------
    InvalidInputError
        Mismatched shapes, non-finite values or costs that are not symmetric positive
        (semi-)definite.
    NumericalError
        The step where the recursion overflows float64 on finite input (e.g. a huge
        unstable ``A``).
    """
    A, B = check_dynamics(A, B)
    T, p, q = B.shape
    Q = per_step(Q, "Q", T, (p, p))
    R = per_step(R, "R", T, (q, q))
    Qf = per_step(Q_final, "Q_final", 1, (p, p))[0]
    check_psd(Q, "Q", definite=False)
    check_psd(R, "R", definite=True)
    check_psd(Qf, "Q_final", definite=False)
    return lqr_recursion(A, B, Q, R, Qf)[0]
