r"""What LQG-MP's 2-D and 3-D estimates share: the methods, the result, the joint
recursion of true and estimated state, and the Gaussian helpers (truncation by a half-space,
the propagation check, the eigen-factor), and the 2-D per-step helpers of the sigma and
truncation methods. :mod:`riskplan.control.lqgmp` and :mod:`riskplan.control.lqgmp3d` both
build on it.

The truncation method (Patil, van den Berg & Alterovitz, RSS 2011, section IV-D) conditions
the joint Gaussian ``N(μ, Σ)`` on each half-space ``cᵀξ ≤ b`` in turn by moment matching of
the truncated normal (``_truncate``): with ``σ² = cᵀΣc``, ``α = (b − cᵀμ)/σ`` and
``λ = φ(α)/Φ(α)``,

.. math::

    \mu' = \mu - \frac{\lambda}{\sigma} \Sigma c, \qquad
    \Sigma' = \Sigma - \frac{\alpha \lambda + \lambda^2}{\sigma^2} \Sigma c c^\top \Sigma

so later steps see only the trajectories that survived. Each step's bound is
``p_t = Σ_j (1 − Φ(b_j))`` over the half-spaces of the body points' free regions (taken before
the step's truncations), and ``P(collision free) = ∏_t (1 − min(1, p_t))``."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from riskplan.control.lqg import LQGController
from riskplan.errors import InvalidInputError

__all__ = ["METHODS", "LQGMPResult", "joint_covariances"]

METHODS = ("sigma", "truncation", "sampling")


# whitened variance below which a direction counts as deterministic (no truncation, no bound)
_TINY = 1e-300


@dataclass(frozen=True, eq=False)
class LQGMPResult:
    """LQG-MP estimate of one plan.

    ``p_success``, ``p_collision_free``, ``p_goal`` (floats); ``p_free_steps (T,)`` the
    per-step factor of ``p_collision_free`` (steps 1..T); ``mean (T + 1, 2p)`` and
    ``cov (T + 1, 2p, 2p)`` of ``ξ_t = (x̄_t, x̂_t)`` (the mean is zero for ``"sigma"``;
    after truncation for ``"truncation"``, and carries the drift with ``drift=True``); ``method``;
    ``n_goal_samples``: the draws of the goal test (0 where not recorded: the 2-D
    recursion of :func:`~riskplan.control.lqgmp.lqgmp` leaves it) and
    ``p_success_se``: the Monte Carlo standard error of ``p_success`` from those draws,
    ``p_free · sqrt(p̃(1 − p̃)/n)`` (``p̃`` as :func:`riskplan.control.lqgmp3d.lqgmp_3d`'s
    ``goal_se``; NaN where not sampled), or with the exact goal test ``p_free`` times its
    quadrature's error bound (``n_goal_samples`` 0); ``goal_test``: ``"draws"`` or
    ``"exact"`` (:func:`riskplan.control.lqgmp3d.lqgmp_3d`'s ``goal``).
    """

    p_success: float
    p_collision_free: float
    p_goal: float
    p_free_steps: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    method: str
    n_goal_samples: int = 0
    p_success_se: float = float("nan")
    goal_test: str = "draws"


def joint_covariances(
    ctrl: LQGController, drift: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``F (T, 2n, 2n)``, the noise term ``G diag(M, N) Gᵀ (T, 2n, 2n)`` and the mean input
    ``G (d̄, 0) (T, 2n)`` of the recursion (zero unless ``drift``; then ``M − d̄ d̄ᵀ``
    replaces the second moment ``M``), for the controller's model
    (:meth:`~riskplan.control.lqg.LQGController.model`: ``n = p``, or ``p + q`` with the
    disturbance state).

    Parameters
    ----------
    ctrl : LQGController
        The controller (its model, ``L`` and ``K``).
    drift : bool
        Carry the mean one-step deviation ``lin.drift`` (not for a disturbance-state
        controller).

    Returns
    -------
    F : numpy.ndarray
        ``(T, 2n, 2n)`` transition of the joint state ``(x_t, x̂_t)``.
    noise : numpy.ndarray
        ``(T, 2n, 2n)``, ``G diag(M, N) Gᵀ``.
    mean_input : numpy.ndarray
        ``(T, 2n)``, ``G (d̄, 0)``.
    """
    lin = ctrl.lin
    if drift and ctrl.disturbance:
        raise InvalidInputError(
            "drift=True: not defined for a disturbance-state controller (its d carries the persistent shift)"
        )
    A, B, H, M, N = ctrl.model()
    L, K = ctrl.L, ctrl.K
    d = lin.drift if drift else np.zeros(A.shape[:2])
    if drift:
        M = M - d[:, :, None] * d[:, None, :]
    T, p, _ = A.shape
    m = H.shape[1]
    BL = B @ L
    KHA = K @ H @ A
    F = np.empty((T, 2 * p, 2 * p))
    F[:, :p, :p] = A
    F[:, :p, p:] = BL
    F[:, p:, :p] = KHA
    F[:, p:, p:] = A + BL - KHA
    G = np.zeros((T, 2 * p, p + m))
    G[:, :p, :p] = np.eye(p)
    G[:, p:, :p] = K @ H
    G[:, p:, p:] = K
    Wn = np.zeros((T, p + m, p + m))
    Wn[:, :p, :p] = M
    Wn[:, p:, p:] = N
    return F, G @ Wn @ np.swapaxes(G, 1, 2), np.einsum("tij,tj->ti", G[:, :, :p], d)


def _truncate(mu, S, c, b):
    """Condition ``N(mu, S)`` on ``cᵀξ <= b`` (moment matching of the truncated normal)."""
    from scipy.special import ndtr

    Sc = S @ c
    var = float(c @ Sc)
    if var <= _TINY:
        return mu, S
    sd = math.sqrt(var)
    alpha = (b - float(c @ mu)) / sd
    Phi = float(ndtr(alpha))
    if Phi <= 1e-300:
        return mu, S  # the whole mass is beyond: nothing sensible to keep; the bound says p = 1
    lam = math.exp(-0.5 * alpha * alpha) / math.sqrt(2 * math.pi) / Phi
    mu = mu - Sc * (lam / sd)
    S = S - np.outer(Sc, Sc) * ((alpha * lam + lam * lam) / var)
    return mu, 0.5 * (S + S.T)


def _check_propagation(mean: np.ndarray, cov: np.ndarray, first: int = 0) -> None:
    """Raise :class:`NumericalError` naming the first step whose propagated mean or covariance
    (states ``first, first + 1, ..``) left float64's range (finite gains of a very unstable
    model can still overflow it)."""
    ok = np.isfinite(mean).all(axis=-1) & np.isfinite(cov).all(axis=(-2, -1))
    if not ok.all():
        from riskplan.errors import NumericalError

        t = first + int(np.flatnonzero(~ok)[0])
        raise NumericalError(
            f"LQG-MP covariance propagation overflowed float64 at step {t - 1} (state {t})",
            step=t - 1,
        )


def _factor(S: np.ndarray) -> np.ndarray:
    """``V`` with ``V Vᵀ = S`` for a symmetric positive semi-definite ``S`` (eigen-factor)."""
    w, v = np.linalg.eigh(0.5 * (S + S.T))
    return v * np.sqrt(np.clip(w, 0.0, None))


def _closed_loop_draws(gen, n: int, T: int, P0, F, dm, Qn):
    """``n`` draws of the closed loop's joint deviation ``xi = (x - x̄, x̂ - x̄)`` step by step
    (``method="sampling"`` of both LQG-MP estimators): ``xi_0 = (N(0, P0), 0)``,
    ``xi_{t+1} = F_t xi_t + dm_t + N(0, Qn_t)``; yields ``(t, xi_{t+1})``, ``xi (n, 2 nz)``,
    for ``t = 0 .. T-1``, drawing from ``gen`` in that order."""
    nz = F.shape[1] // 2
    xi = np.zeros((n, 2 * nz))
    xi[:, :nz] = gen.standard_normal((n, nz)) @ _factor(P0).T
    for t in range(T):
        xi = xi @ F[t].T + dm[t] + gen.standard_normal((n, 2 * nz)) @ _factor(Qn[t]).T
        yield t, xi


def _regularised(Sp: np.ndarray) -> np.ndarray | None:
    """A point's ``(2, 2)`` covariance as both sigma paths use it: ``None`` for a
    deterministic point (largest variance ≤ 1e-24: no risk outside an obstacle), else the
    covariance with a jitter of 1e-9 of its largest variance where it is near-singular
    (smallest ≤ 1e-12 of the largest), as :func:`_sigma_free` does: a rank-1 spread keeps
    its distances along its direction and gets a Cholesky factor."""
    ev = np.linalg.eigvalsh(Sp)
    if ev[-1] <= 1e-24:
        return None
    if ev[0] <= 1e-12 * ev[-1]:
        return Sp + 1e-9 * ev[-1] * np.eye(2)
    return Sp


def _point_factor(Sp: np.ndarray, t: int) -> np.ndarray:
    """The whitening factor of a point covariance at step ``t``; one that has none after
    :func:`_regularised` (a degenerate linear model) is a :class:`NumericalError` naming the
    step, not bad input: a plan evaluation counts it as a failed candidate."""
    from riskplan.collision import precision_cholesky_from_covariance
    from riskplan.errors import NumericalError

    try:
        return precision_cholesky_from_covariance(Sp)
    except InvalidInputError as exc:
        raise NumericalError(
            f"LQG-MP: the position covariance at step {t} has no Cholesky factor ({exc})", step=t
        ) from exc


def _mix(col, W, base, mu, S):
    """Means ``(..., n, 2)`` and covariances ``(..., n, 2, 2)`` of the points
    ``base + W d`` for mean deviations ``mu (..., ≥p)`` and covariances ``S (..., ≥p, ≥p)``."""
    Sp = S[..., col[:, None, :, None], col[None, :, None, :]]  # (..., k, k, 2, 2)
    pts = base + np.einsum("rk,...kd->...rd", W, mu[..., col])
    covs = np.einsum("ri,rj,...ijab->...rab", W, W, Sp)
    return pts, covs


def _truncation_step(col, W, base, mu, S, p, env, t, cutoff):
    """``method="truncation"`` at step ``t``: each body point's bound against ``env`` under
    the truncations so far, then the truncation of ``N(mu, S)`` by its free region.
    Returns the truncated ``mu``, ``S`` and the step's factor of ``P(collision free)``."""
    from riskplan.collision import free_region

    nz = mu.shape[0] // 2
    p_t = 0.0
    for j in range(len(base)):
        sl = slice(j, j + 1)
        # this point under the truncations so far
        pj, Sp = _mix(col, W[sl], base[sl], mu[:p], S)
        pj, Sp = pj[0], _regularised(Sp[0])
        if Sp is None:
            continue  # a deterministic point outside every obstacle: no risk
        U = _point_factor(Sp, t)
        fr = free_region(pj, U, env, cutoff=cutoff)
        p_t += float(fr.bound_terms.sum())
        for nrm, off in zip(fr.normals, fr.offsets):
            c = np.zeros(2 * nz)
            for i in np.flatnonzero(W[j]):
                c[col[i]] += W[j, i] * nrm
            mu, S = _truncate(mu, S, c, off - float(nrm @ base[j]))
    return mu, S, 1.0 - min(1.0, p_t)


def _sigma_step(pts, covs, env, t, cutoff) -> float:
    """``method="sigma"`` at step ``t`` (the per-step path): the factor of ``P(collision
    free)`` from the least whitened distance of the body points ``pts (n, 2)`` with
    covariances ``covs (n, 2, 2)`` to ``env``."""
    from riskplan.collision import free_region

    c_min = math.inf
    for j in range(len(pts)):
        Sp = _regularised(covs[j])
        if Sp is None:
            continue
        U = _point_factor(Sp, t)
        d = free_region(pts[j], U, env, cutoff=cutoff).distances
        if d.size:
            c_min = min(c_min, float(d.min()))
    return 1.0 if math.isinf(c_min) else -math.expm1(-0.5 * c_min * c_min)
