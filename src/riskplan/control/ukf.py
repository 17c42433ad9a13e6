"""Unscented Kalman filter (Julier & Uhlmann, Proc. IEEE 2004; the scaled sigma points of
Wan & van der Merwe, "The unscented Kalman filter for nonlinear estimation", 2000), an
alternative estimator of :func:`~riskplan.control.execute` (``estimator="ukf"``; beyond
the deformable-planning paper, which uses the Kalman filter).

Sigma points of ``N(x̂, P)`` in ``n`` dimensions, ``λ = α² (n + κ) − n``::

    χ_0 = x̂,   χ_i = x̂ + (√((n + λ) P))_i,   χ_{n+i} = x̂ − (√((n + λ) P))_i,   i = 1 .. n
    W^m_0 = λ / (n + λ),   W^c_0 = λ / (n + λ) + 1 − α² + β,   W^m_i = W^c_i = 1 / (2 (n + λ))

with the matrix square root a Cholesky factor (columns). Defaults ``α = 1``, ``β = 2``,
``κ = 0`` (:data:`ALPHA`, :data:`BETA`, :data:`KAPPA`): ``α = 1`` keeps the points at
``±√n`` standard deviations, so all weights are positive for ``n ≥ 1`` with ``κ = 0``
(``λ = 0``: ``W^m_0 = 0``) and the covariance stays positive semi-definite; ``β = 2`` is
optimal for a Gaussian prior (it matches the fourth moment). A small ``α`` (``10⁻³``,
the common choice) makes ``W^c_0`` large and negative and, in float64, costs digits on
the linear oracle for no gain on smooth maps.

One step (additive noises ``m ~ N(0, M)``, ``n ~ N(0, N)``), ``f`` the motion and ``h`` the
measurement::

    predict   χ⁻_i = f(χ_i),   x̂⁻ = Σ W^m_i χ⁻_i,   P⁻ = Σ W^c_i (χ⁻_i − x̂⁻)(·)ᵀ + M
    update    sigma points of N(x̂⁻, P⁻) → ζ_i = h(χ_i),   ẑ = Σ W^m_i ζ_i,
              S = Σ W^c_i (ζ_i − ẑ)(·)ᵀ + N,   C = Σ W^c_i (χ_i − x̂⁻)(ζ_i − ẑ)ᵀ
              K = C S⁻¹,   x̂ = x̂⁻ + K (z − ẑ),   P = P⁻ − K S Kᵀ

For linear ``f`` and ``h`` the unscented transform is exact, so the recursion equals the
Kalman filter (:mod:`riskplan.control.kalman`) to float64 round-off (the oracle of the
tests).

The recursion is written here rather than taken from filterpy (``filterpy.kalman.
UnscentedKalmanFilter``): filterpy keeps the filter as a mutable object whose ``fx(x, dt)``
/ ``hx(x)`` signatures carry no step index or control, while the execution needs a
time-varying motion ``f_t(x, ū_t)`` about the plan, our typed errors on a singular
innovation covariance, and no new dependency for some thirty lines of linear algebra; the
linear-model oracle tests the recursion independently of either implementation.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from riskplan.errors import InvalidInputError, NumericalError

__all__ = [
    "ALPHA",
    "BETA",
    "KAPPA",
    "execution_ukf",
    "material_measurement",
    "sigma_points",
    "ukf_step",
    "unscented_transform",
]

#: Spread of the sigma points (module docstring).
ALPHA = 1.0
#: Prior-distribution parameter, 2 for a Gaussian.
BETA = 2.0
#: Secondary scaling.
KAPPA = 0.0


def sigma_points(mean, cov, alpha: float = ALPHA, beta: float = BETA, kappa: float = KAPPA):
    """Scaled sigma points and weights of ``N(mean, cov)`` (module docstring).

    Parameters
    ----------
    mean : array_like
        ``(n,)`` mean.
    cov : array_like
        ``(n, n)`` covariance, symmetric positive semi-definite.
    alpha, beta, kappa : float
        Scaling parameters (:data:`ALPHA`, :data:`BETA`, :data:`KAPPA`); ``n + λ > 0``.

    Returns
    -------
    chi : numpy.ndarray
        ``(2 n + 1, n)`` sigma points.
    wm : numpy.ndarray
        ``(2 n + 1,)`` mean weights.
    wc : numpy.ndarray
        ``(2 n + 1,)`` covariance weights.
    """
    x = np.asarray(mean, dtype=np.float64)
    P = np.asarray(cov, dtype=np.float64)
    n = x.shape[0]
    if x.ndim != 1 or P.shape != (n, n):
        raise InvalidInputError(f"cov: expected shape ({n}, {n}), got {P.shape}")
    lam = alpha * alpha * (n + kappa) - n
    if not n + lam > 0:
        raise InvalidInputError(f"alpha, kappa: need n + λ > 0, got {n + lam}")
    S = _sqrt_psd((n + lam) * P)
    chi = np.empty((2 * n + 1, n))
    chi[0] = x
    chi[1 : n + 1] = x + S.T
    chi[n + 1 :] = x - S.T
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = lam / (n + lam) + 1.0 - alpha * alpha + beta
    return chi, wm, wc


def _sqrt_psd(P: np.ndarray) -> np.ndarray:
    """A factor ``S`` with ``S Sᵀ = P``: Cholesky, or a symmetric eigen-factor where ``P``
    is only semi-definite (a known start state, ``P0 = 0``)."""
    P = 0.5 * (P + P.T)
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(P)
        if not np.all(np.isfinite(w)) or w.min() < -1e-9 * max(1.0, abs(w).max()):
            raise NumericalError("UKF: covariance is not positive semi-definite") from None
        return V * np.sqrt(np.clip(w, 0.0, None))


def unscented_transform(
    f: Callable,
    mean,
    cov,
    noise_cov=None,
    alpha: float = ALPHA,
    beta: float = BETA,
    kappa: float = KAPPA,
):
    """Mean and covariance of ``f(x) + w``, ``x ~ N(mean, cov)``, ``w ~ N(0, noise_cov)``,
    by the unscented transform.

    Parameters
    ----------
    f : callable
        ``f(x (n,)) -> (k,)``.
    mean, cov : array_like
        ``(n,)``, ``(n, n)``.
    noise_cov : array_like, optional
        ``(k, k)`` additive noise covariance (default none).
    alpha, beta, kappa : float
        Sigma-point parameters (:func:`sigma_points`).

    Returns
    -------
    y_mean : numpy.ndarray
        ``(k,)``.
    y_cov : numpy.ndarray
        ``(k, k)``.
    cross : numpy.ndarray
        ``(n, k)`` cross covariance ``Cov(x, f(x))``.
    """
    chi, wm, wc = sigma_points(mean, cov, alpha, beta, kappa)
    Y = np.stack([np.asarray(f(c), dtype=np.float64) for c in chi])
    ym = wm @ Y
    dY = Y - ym
    dX = chi - chi[0]
    cov_y = (wc[:, None] * dY).T @ dY
    if noise_cov is not None:
        cov_y = cov_y + np.asarray(noise_cov, dtype=np.float64)
    cross = (wc[:, None] * dX).T @ dY
    return ym, 0.5 * (cov_y + cov_y.T), cross


def ukf_step(
    xhat,
    P,
    f: Callable,
    h: Callable,
    M,
    N,
    z,
    alpha: float = ALPHA,
    beta: float = BETA,
    kappa: float = KAPPA,
):
    """One predict + update of the UKF (module docstring).

    Parameters
    ----------
    xhat : array_like
        ``(n,)`` estimate at ``t``.
    P : array_like
        ``(n, n)`` its covariance.
    f : callable
        Motion ``f(x (n,)) -> (n,)`` from ``t`` to ``t + 1`` (the control bound in).
    h : callable
        Measurement ``h(x (n,)) -> (m,)`` at ``t + 1``.
    M : array_like
        ``(n, n)`` process noise covariance.
    N : array_like
        ``(m, m)`` measurement noise covariance.
    z : array_like
        ``(m,)`` measurement at ``t + 1``.
    alpha, beta, kappa : float
        Sigma-point parameters (:func:`sigma_points`).

    Returns
    -------
    xhat : numpy.ndarray
        ``(n,)`` estimate at ``t + 1``.
    P : numpy.ndarray
        ``(n, n)`` its covariance.
    """
    xp, Pp, _ = unscented_transform(f, xhat, P, M, alpha, beta, kappa)
    zm, S, C = unscented_transform(h, xp, Pp, N, alpha, beta, kappa)
    try:
        K = np.linalg.solve(S, C.T).T  # S symmetric
    except np.linalg.LinAlgError as exc:
        raise NumericalError(f"UKF: singular innovation covariance ({exc})") from exc
    x = xp + K @ (np.asarray(z, dtype=np.float64) - zm)
    Pn = Pp - K @ S @ K.T
    Pn = 0.5 * (Pn + Pn.T)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(Pn))):
        raise NumericalError("UKF: non-finite estimate")
    return x, Pn


def material_measurement(sim, plan):
    """The measurement of a simulator whose reduced state is the material pose (the needle
    with ``frame="material"``), as a function of the reduced state, or ``None`` for others.

    ``h_t(ξ) = measure(y(x*_t + ξ)) − measure(y*_t)``, ``y(X)`` the full state whose material
    pose is ``X`` at step ``t``, its tissue response recomputed under ``plan.params``
    (``sim.transfer_state``): the world position ``X + u(X; s)`` the sensor sees, nonlinear
    in ``X`` through the deformation (the EKF uses its Jacobian ``H_t`` at ``ξ = 0``,
    :meth:`~riskplan.scenarios.needle.NeedleScenario.observation_jacobian`).

    Parameters
    ----------
    sim : Simulator
        The simulator.
    plan : NominalPlan
        The plan ``(y*, x*)``.

    Returns
    -------
    callable or None
        ``h(t, xi (p,)) -> (m,)`` for ``1 ≤ t ≤ T``.
    """
    import dataclasses

    transfer = getattr(sim, "transfer_state", None)
    if getattr(sim, "frame", None) != "material" or not callable(transfer):
        return None
    zero = np.zeros(sim.obs_dim)

    def h(t, xi):
        y = plan.states[t]
        moved = dataclasses.replace(y, material=np.asarray(plan.reduced[t]) + xi)
        z = sim.measure(transfer(moved, plan.params), noise=zero)
        return np.asarray(z, dtype=np.float64) - np.asarray(sim.measure(y, noise=zero))

    return h


def execution_ukf(sim, plan, controller):
    """The UKF update of :func:`~riskplan.control.execute` (``estimator="ukf"``).

    Motion: the controller's linear(ised) model, ``f_t(ξ) = A_t ξ + B_t ū_t`` (the
    simulator's own step acts on its full state, of which the reduced state is only a
    projection, so it cannot move sigma points of the reduced state). Measurement: the
    simulator's ``h`` about the plan, ``h_t(ξ) = observe(x*_{t+1} + ξ_x) − observe(x*_{t+1})``
    (plus the bias columns of an augmented ``H_t``) for a simulator without a full-state
    ``measure``; the needle in its material frame: the sensed world position of the
    material pose ``x*_{t+1} + ξ`` through the tissue's response under the plan's parameters
    (``material_measurement``); else the linear ``H_t ξ``. The covariance starts at
    ``controller.P0``.

    Parameters
    ----------
    sim : Simulator
        The simulator executed.
    plan : NominalPlan
        The plan.
    controller : LQGController
        Its model ``(A, B, H, M, N)`` and ``P0``.

    Returns
    -------
    callable
        ``update(t, xhat, ubar, zbar) -> xhat`` (the covariance is kept inside).
    """
    A, B, H, M, N = controller.model()
    T = A.shape[0]
    M = np.broadcast_to(M, (T,) + A.shape[1:])
    N = np.broadcast_to(N, (T,) + N.shape[-2:])
    p = plan.reduced.shape[1]
    nonlinear = getattr(sim, "measure", None) is None
    material = material_measurement(sim, plan)
    state = {"P": np.asarray(controller.P0, dtype=np.float64)}

    def observe(x):
        return np.asarray(sim.observe(x, noise=np.zeros(sim.obs_dim)), dtype=np.float64)

    def update(t, xhat, ubar, zbar):
        if nonlinear:
            z0 = observe(plan.reduced[t + 1])

            def h(xi):
                return observe(plan.reduced[t + 1] + xi[:p]) - z0 + H[t][:, p:] @ xi[p:]
        elif material is not None:

            def h(xi):
                return material(t + 1, xi[:p]) + H[t][:, p:] @ xi[p:]
        else:

            def h(xi):
                return H[t] @ xi

        x, state["P"] = ukf_step(
            xhat, state["P"], lambda xi: A[t] @ xi + B[t] @ ubar, h, M[t], N[t], zbar
        )
        return x

    return update
