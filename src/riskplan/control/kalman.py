"""Time-varying Kalman filter gains in filter (corrector) form (deformable-planning paper
section IV-C; van den Berg, Abbeel & Goldberg, IJRR 2011, section IV).

Model (deviations from the nominal plan, paper eq. 4), ``t = 0 .. T-1``:

    x_{t+1} = A_t x_t + B_t u_t + m_t,        m_t ~ N(0, M_t)
    z_{t+1} = H_t x_{t+1} + n_t,              n_t ~ N(0, N_t)

so step ``t`` of the arrays holds the dynamics from ``t`` to ``t + 1`` and the measurement
taken at ``t + 1`` (there is no measurement of ``x_0``; its estimate has covariance ``P0``).
Filter, starting from ``x̂_0`` with covariance ``P_0``::

    process update      x̂⁻_{t+1} = A_t x̂_t + B_t u_t,          P⁻_{t+1} = A_t P_t A_tᵀ + M_t
    gain                K_t = P⁻_{t+1} H_tᵀ (H_t P⁻_{t+1} H_tᵀ + N_t)⁻¹
    measurement update  x̂_{t+1} = x̂⁻_{t+1} + K_t (z_{t+1} − H_t x̂⁻_{t+1})
                        P_{t+1} = (I − K_t H_t) P⁻_{t+1}

``kalman_gains`` returns ``K[t] = K_t`` and ``P[t] = P_{t+1}`` (the *posterior* covariance
after the measurement at ``t + 1``). python-control's ``dlqe`` returns the stationary
*predictor* gain ``A P⁻ Hᵀ (H P⁻ Hᵀ + N)⁻¹`` and the prior ``P⁻`` (python-control issue
1173); the filter gain here is ``P⁻ Hᵀ (H P⁻ Hᵀ + N)⁻¹``.
"""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array, check_dynamics, check_psd, per_step, raise_overflow
from riskplan.errors import InvalidInputError

__all__ = ["kalman_gains", "kalman_recursion"]


def kalman_recursion(A: np.ndarray, H: np.ndarray, M: np.ndarray, N: np.ndarray, P0: np.ndarray):
    """The recursion without checks: ``A (T, p, p)``, ``H (T, m, p)``, ``M (T, p, p)``,
    ``N (T, m, m)``, ``P0 (p, p)``; returns ``(K (T, p, m), P (T, p, p))``.

    Parameters
    ----------
    A : numpy.ndarray
        ``(T, p, p)`` state matrices.
    H : numpy.ndarray
        ``(T, m, p)`` observation matrices.
    M : numpy.ndarray
        ``(T, p, p)`` process noise covariances.
    N : numpy.ndarray
        ``(T, m, m)`` measurement noise covariances.
    P0 : numpy.ndarray
        ``(p, p)`` covariance of the initial estimate.

    Returns
    -------
    K : numpy.ndarray
        ``(T, p, m)`` filter gains (equations of :func:`kalman_gains`).
    P : numpy.ndarray
        ``(T, p, p)`` posterior covariances.
    """
    T, p, _ = A.shape
    m = H.shape[1]
    K = np.empty((T, p, m))
    P = np.empty((T, p, p))
    I = np.eye(p)
    Pt = P0
    for t in range(T):
        with np.errstate(over="ignore", invalid="ignore"):
            Pp = A[t] @ Pt @ A[t].T + M[t]
            Ht = H[t]
            S = Ht @ Pp @ Ht.T + N[t]
            try:
                Kt = np.linalg.solve(S, Ht @ Pp).T  # S symmetric: (S^-1 H P⁻)ᵀ = P⁻ Hᵀ S^-1
            except np.linalg.LinAlgError as exc:  # a singular matrix after an overflow
                raise_overflow("Kalman covariance recursion", t, exc)
            Pn = (I - Kt @ Ht) @ Pp
            Pt = 0.5 * (Pn + Pn.T)
        if not (np.isfinite(Kt).all() and np.isfinite(Pt).all()):
            raise_overflow("Kalman covariance recursion", t)
        K[t] = Kt
        P[t] = Pt
    return K, P


def kalman_gains(A, H, M, N, P0) -> tuple[np.ndarray, np.ndarray]:
    r"""Kalman gains and posterior covariances in filter form (paper IV-C).

    .. math::

        P^-_{t+1} = A_t P_t A_t^\top + M_t, \qquad
        K_t = P^-_{t+1} H_t^\top (H_t P^-_{t+1} H_t^\top + N_t)^{-1}, \qquad
        P_{t+1} = (I - K_t H_t) P^-_{t+1}.

    Parameters
    ----------
    A : array_like
        ``(T, p, p)`` state matrices.
    H : array_like
        ``(m, p)`` or ``(T, m, p)`` observation matrices; ``H[t]`` observes ``x_{t+1}``.
    M : array_like
        ``(p, p)`` or ``(T, p, p)`` process noise covariance, symmetric positive
        semi-definite.
    N : array_like
        ``(m, m)`` or ``(T, m, m)`` measurement noise covariance, symmetric positive
        definite.
    P0 : array_like
        ``(p, p)`` covariance of the initial estimate, symmetric positive semi-definite.

    Returns
    -------
    K : numpy.ndarray
        ``(T, p, m)``; ``K[t]`` corrects the estimate of ``x_{t+1}`` with ``z_{t+1}``.
    P : numpy.ndarray
        ``(T, p, p)``, ``P[t] = Cov(x_{t+1} − x̂_{t+1})``.

    Raises
    ------
    NumericalError
        The step where the recursion overflows float64 on finite input.
    """
    A, _ = check_dynamics(A)
    T, p, _ = A.shape
    Harr = as_array(H, "H", min_ndim=2)
    m = Harr.shape[-2]
    H = per_step(Harr, "H", T, (m, p))
    M = per_step(M, "M", T, (p, p))
    N = per_step(N, "N", T, (m, m))
    P0 = as_array(P0, "P0", shape=(p, p))
    check_psd(M, "M", definite=False)
    check_psd(N, "N", definite=True)
    check_psd(P0, "P0", definite=False)
    if m < 1:
        raise InvalidInputError(f"H: expected at least one measurement row, got shape {Harr.shape}")
    return kalman_recursion(A, H, M, N, P0)
