r"""LQG-MP's a-priori distributions beyond the linear model, for a simulator whose true state
moves linearly in a pose for a fixed control and is sensed and checked through a nonlinear
map of it — the 3-D needle (:mod:`riskplan.scenarios.needle3d_moments`): the material pose
``m`` steps as ``m' = K(u) m`` and the world tip is ``x(m) = X + u(X; e₃)``, the tissue's push.

The controller (:class:`~riskplan.control.lqg.LQGController`: gains ``L_t``, Kalman gains
``K_t``, its model ``A_t, B_t, H_t`` in the reduced state) stays what it is; what changes is
the model of the *true* system the recursion of van den Berg et al. (IJRR 2011) runs it
against. The joint state is ``ξ = (δm, x̂)`` (true material deviation, the filter's
estimate) and, with ``δu = L_t x̂ + w``, ``w ~ N(0, Σ_w)`` (the actuation noise):

* **the step, mean to second order, covariance to first** (a consistent expansion in the
  noise: the bilinear and quadratic terms move the mean at ``O(σ²)``; their share of the
  covariance is ``O(σ⁴)``, the order of the linear × cubic cross terms that a Gaussian
  closure leaves out and that cancel it on a rotation, which keeps ``|e_k| = 1`` — measured:
  the closure's ``e``-spread 30–50 % above the executions', the first-order one within 5 %):

  .. math::

      E[\delta m'] = K E[\delta m] + B_m E[\delta u]
          + \sum_k K_k \big(\mathrm{Cov}(\delta m, \delta u_k) + E[\delta u_k] E[\delta m]\big)
          + \tfrac12 \sum_{kl} K_{kl} m^* \big(\mathrm{Cov}(\delta u)_{kl} + E[\delta u_k] E[\delta u_l]\big)

      \mathrm{Cov}(\delta m') = [K, B_m L_t]\, S\, [K, B_m L_t]^\top + B_m \Sigma_w B_m^\top,
      \qquad B_m = [K_1 m^*, \dots, K_q m^*]

* **the measurement and the checked position** through the statistical linearisation of
  the tip over the predicted spread (``sim.tip_moments``: ``x ≈ x* + Δ + Φ δm + ε``,
  ``ε ~ N(0, R)``); the filter sees ``z̄' = Φ δm' + Δ + ε + n`` and updates
  ``x̂' = (I − K_t H_t)(A_t + B_t L_t) x̂ + K_t z̄'``;
* **the target** moves with the tip (the push deforms it): the goal test takes the tip
  relative to the deformed target's centre, statistically linearised the same way
  (``kind="relative"``), in the plan's deformed target.

Control saturation is not modelled (the clip of ``u* + L x̂ + w`` at the bounds). The
result, :class:`SecondOrderModel`, feeds :func:`riskplan.control.lqgmp3d.lqgmp_3d`
(``moments=``), whose truncation, per-step, sigma and sampling methods run on it unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_array
from riskplan.errors import InvalidInputError

__all__ = ["SecondOrderModel", "second_order_model", "structured_linearization"]


@dataclass(frozen=True, eq=False)
class SecondOrderModel:
    """The joint recursion ``ξ_{t+1} = F_t ξ_t + c_t + noise(Q_t)`` of ``ξ = (δm, x̂)`` and
    the maps from ``ξ`` to the checked position (module docstring).

    ``F (T, 2p, 2p)``, ``c (T, 2p)``, ``Q (T, 2p, 2p)``; ``P (T, 3, 2p)``, ``offset (T, 3)``
    and ``resid (T, 3, 3)``: the position at step ``t + 1`` is ``x*_{t+1} + offset_t + P_t ξ +
    ε_t``, ``ε_t ~ N(0, resid_t)``, with ``cross (T, 2p, 3) = Cov(ξ_{t+1}, ε_t)`` (the filter
    saw the same ε where the checked position is the sensed one); ``goal_P (3, 2p)``,
    ``goal_offset (3,)``, ``goal_resid (3, 3)``: the final position relative to the moving
    target the same way; ``P0 (2p, 2p)`` the initial covariance."""

    F: np.ndarray
    c: np.ndarray
    Q: np.ndarray
    P: np.ndarray
    offset: np.ndarray
    resid: np.ndarray
    cross: np.ndarray
    goal_P: np.ndarray
    goal_offset: np.ndarray
    goal_resid: np.ndarray
    P0: np.ndarray

    @property
    def n_steps(self) -> int:
        """``T``, the number of steps."""
        return self.F.shape[0]


def _second_order_mean(dK, d2K, ms, mu_m, Eu, Cu, Cmu) -> np.ndarray:
    """``E[Σ_k K_k δu_k δm + ½ Σ_kl K_kl m* δu_k δu_l]`` (module docstring)."""
    q = dK.shape[0]
    e = np.zeros(ms.shape[0])
    for k in range(q):
        e += dK[k] @ (Cmu[:, k] + Eu[k] * mu_m)
        for j in range(q):
            e += 0.5 * (Cu[k, j] + Eu[k] * Eu[j]) * (d2K[k, j] @ ms)
    return e


def _check(sim, plan, controller, actuation_cov):
    from riskplan.control.lqg import LQGController
    from riskplan.control.plan import NominalPlan

    if not isinstance(plan, NominalPlan):
        raise InvalidInputError(f"plan: expected a NominalPlan, got {type(plan).__name__}")
    if not isinstance(controller, LQGController) or controller.n_steps != plan.n_steps:
        raise InvalidInputError(
            "controller: expected the LQGController of this plan (same number of steps)"
        )
    if controller.disturbance:
        raise InvalidInputError("controller: the disturbance-state controller is not supported")
    for hook in ("material_step_derivatives", "tip_moments"):
        if not callable(getattr(sim, hook, None)):
            raise InvalidInputError(f"sim: has no {hook}() (see riskplan.scenarios.needle3d)")
    q = plan.controls.shape[1]
    W = as_array(actuation_cov, "actuation_cov", shape=(q, q))
    if not np.allclose(W, W.T) or np.linalg.eigvalsh(W)[0] < 0:
        raise InvalidInputError("actuation_cov: expected a symmetric positive semi-definite matrix")
    return W


def second_order_model(sim, plan, controller, actuation_cov) -> SecondOrderModel:
    """The :class:`SecondOrderModel` of ``plan`` under ``controller`` (module docstring).

    Parameters
    ----------
    sim : Simulator
        Provides ``material_step_derivatives(state, u)`` and ``tip_moments(state, mean, cov,
        params, kind)`` (:class:`riskplan.scenarios.needle3d.Needle3DScenario`).
    plan : NominalPlan
        The plan (its states hold the material poses ``m*_t``).
    controller : LQGController
        The plan's controller (not the disturbance-state one).
    actuation_cov : array_like, shape (q, q)
        ``Σ_w``, the covariance of the actuation noise on the control.

    Returns
    -------
    SecondOrderModel
        The recursion and the position maps.
    """
    W = _check(sim, plan, controller, actuation_cov)
    A, B, H, _, N = controller.model()
    L, Kf = controller.L, controller.K
    T, p = plan.n_steps, A.shape[1]
    n2 = 2 * p
    mu = np.zeros(n2)
    S = np.zeros((n2, n2))
    S[:p, :p] = controller.P0
    P0 = S.copy()
    out = {k: [] for k in ("F", "c", "Q", "P", "offset", "resid", "cross")}
    eye = np.eye(p)
    for t in range(T):
        ms, K0, dK, d2K = sim.material_step_derivatives(plan.states[t], plan.controls[t])
        Bm = np.einsum("kij,j->ik", dK, ms)  # (p, q)
        Lx = np.zeros((L.shape[1], n2))
        Lx[:, p:] = L[t]
        Fm = np.hstack([K0, Bm @ L[t]])  # δm' = Fm ξ + Bm w + second order
        Eu, Cu, Cmu = Lx @ mu, Lx @ S @ Lx.T + W, S[:p] @ Lx.T
        e = _second_order_mean(dK, d2K, ms, mu[:p], Eu, Cu, Cmu)
        Mw = Bm @ W @ Bm.T
        mu_m = Fm @ mu + e
        S_m = Fm @ S @ Fm.T + Mw
        y = plan.states[t + 1]
        Phi, Dl, R = sim.tip_moments(y, mu_m, S_m, plan.params, "measured")
        Fx = (eye - Kf[t] @ H[t]) @ (A[t] + B[t] @ L[t])
        G = np.vstack([eye, Kf[t] @ Phi])  # (2p, p): how δm' enters ξ'
        F = G @ Fm
        F[p:, p:] += Fx
        Ge = np.zeros((n2, 3))
        Ge[p:] = Kf[t]
        Q = G @ Mw @ G.T + Ge @ (R + N[t]) @ Ge.T
        c = G @ e + Ge @ Dl
        mu = F @ mu + c
        S = F @ S @ F.T + Q
        S = 0.5 * (S + S.T)
        shared = bool(getattr(sim, "position_is_measured", False))
        if shared:
            Pp, Dp, Rp = Phi, Dl, R
        else:
            Pp, Dp, Rp = sim.tip_moments(y, mu_m, S_m, plan.params, "position")
        out["F"].append(F)
        out["c"].append(c)
        out["Q"].append(Q)
        out["P"].append(np.hstack([Pp, np.zeros((3, p))]))
        out["offset"].append(Dp)
        out["resid"].append(Rp)
        out["cross"].append(Ge @ R if shared else np.zeros((n2, 3)))
    Pg, Dg, Rg = sim.tip_moments(plan.states[T], mu[:p], S[:p, :p], plan.params, "relative")
    arr = {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}
    return SecondOrderModel(
        **arr,
        goal_P=np.hstack([Pg, np.zeros((3, p))]),
        goal_offset=Dg,
        goal_resid=Rg,
        P0=P0,
    )


def structured_linearization(sim, plan, actuation_cov):
    """The :class:`~riskplan.control.linearize.Linearization` of ``plan`` from the
    simulator's ``linear_model(plan, actuation_cov)`` (the 3-D needle: the material step's
    closed form and the tissue's Jacobian, no fit) instead of
    :func:`~riskplan.control.linearize.linearize`'s simulator runs, for the actuation case.

    Parameters
    ----------
    sim : Simulator
        Provides ``linear_model``, ``state_scale`` and ``control_bounds``.
    plan : NominalPlan
        The plan, in the simulator's frame.
    actuation_cov : array_like, shape (q, q)
        ``Σ_w``.

    Returns
    -------
    Linearization
        ``rank`` the state dimension (nothing fitted), no drift; the Bryson scales as
        :func:`~riskplan.control.linearize.linearize` sets them.
    """
    from riskplan.control.linearize import Linearization
    from riskplan.control.plan import NominalPlan

    if not isinstance(plan, NominalPlan):
        raise InvalidInputError(f"plan: expected a NominalPlan, got {type(plan).__name__}")
    if not callable(getattr(sim, "linear_model", None)):
        raise InvalidInputError("sim: has no linear_model() (see riskplan.scenarios.needle3d)")
    A, B, M, H, N = sim.linear_model(plan, actuation_cov)
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    scale = getattr(sim, "state_scale", None)
    return Linearization(
        A=A,
        B=B,
        M=M,
        H=H,
        N=N,
        rank=np.full(A.shape[0], A.shape[1], dtype=np.int64),
        state_scale=None if scale is None else np.asarray(scale, dtype=np.float64),
        control_scale=0.5 * (bounds[:, 1] - bounds[:, 0]),
    )
