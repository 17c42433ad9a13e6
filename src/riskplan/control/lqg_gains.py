r"""The LQG controller of a plan's linearisation (deformable-planning paper, Patil, van den
Berg & Alterovitz, RSS 2011, section IV-C): LQR gains ``L_t``
(:func:`~riskplan.control.lqr_gains`) and Kalman gains ``K_t``
(:func:`~riskplan.control.kalman_gains`) of a :class:`~riskplan.control.Linearization`,
with Bryson's rule for the default costs and, beyond the paper, the model augmented by the
persistent-disturbance state (:func:`augmented_model`). Executing the controller on the true
simulator is :mod:`riskplan.control.lqg`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_array
from riskplan.control.kalman import kalman_gains
from riskplan.control.linearize import Linearization
from riskplan.control.lqr import lqr_gains
from riskplan.errors import InvalidInputError

__all__ = ["LQGController", "augmented_model", "bryson_weights", "lqg_controller"]


def _block_diag(*blocks) -> np.ndarray:
    """The block-diagonal matrix of square ``blocks`` (``None`` skipped)."""
    blocks = [np.asarray(b, dtype=np.float64) for b in blocks if b is not None]
    n = sum(b.shape[0] for b in blocks)
    out = np.zeros((n, n))
    k = 0
    for b in blocks:
        out[k : k + b.shape[0], k : k + b.shape[0]] = b
        k += b.shape[0]
    return out


def augmented_model(lin: Linearization):
    r"""The linear model of the state ``(x̄_t, d)`` with a constant input disturbance
    ``d (q,)`` (beyond the paper; needs ``lin.disturbance``,
    ``linearize(..., disturbance=True)``):

    .. math::

        \begin{bmatrix} \bar x_{t+1} \\ d \end{bmatrix} =
        \begin{bmatrix} A_t & B_t \\ 0 & I \end{bmatrix}
        \begin{bmatrix} \bar x_t \\ d \end{bmatrix} +
        \begin{bmatrix} B_t \\ 0 \end{bmatrix} \bar u_t +
        \begin{bmatrix} m^r_t \\ 0 \end{bmatrix}, \qquad
        \bar z_{t+1} = [H_t \;\; 0] \begin{bmatrix} \bar x_{t+1} \\ d \end{bmatrix} + n_t,

    with :math:`m^r_t \sim N(0, M^r_t)`.

    With a persistent measurement bias in the model (``lin.disturbance.C (T, m, r)``,
    :func:`~riskplan.control.linearize.fit_measurement_bias`) the state is
    ``(x̄_t, d, e)`` of dimension ``p + q + r``, ``e`` constant too, and
    :math:`\bar z_{t+1} = H_t \bar x_{t+1} + C_t e + n_t`, :math:`n_t \sim N(0, N^r_t)`
    (``H = [H_t, 0, C_t]``, ``N = N^r_t``).

    Parameters
    ----------
    lin : Linearization
        A linearisation with its ``disturbance`` model.

    Returns
    -------
    tuple of numpy.ndarray
        ``(A (T, n, n), B (T, n, q), H (T, m, n), M (T, n, n), N (T, m, m))``, ``n = p + q``
        (``p + q + r`` with a measurement bias), with ``M = diag(M^r_t, 0)``: ``d`` does not
        change during an execution.
    """
    if lin.disturbance is None:
        raise InvalidInputError("lin: has no disturbance model; linearize it with disturbance=True")
    T, p, q = lin.B.shape
    m = lin.H.shape[1]
    dist = lin.disturbance
    r = dist.n_bias
    n = p + q + r
    A = np.zeros((T, n, n))
    A[:, :p, :p] = lin.A
    A[:, :p, p : p + q] = lin.B
    A[:, p:, p:] = np.eye(q + r)
    B = np.zeros((T, n, q))
    B[:, :p] = lin.B
    H = np.zeros((T, m, n))
    H[:, :, :p] = lin.H
    M = np.zeros((T, n, n))
    M[:, :p, :p] = dist.M
    if r:
        H[:, :, p + q :] = dist.C
        return A, B, H, M, np.asarray(dist.N)
    return A, B, H, M, np.asarray(lin.N)


@dataclass(frozen=True, eq=False)
class LQGController:
    """Gains of the LQG controller of one plan.

    ``L (T, q, n)`` feedback (``u_t = u*_t + L_t ξ̂_t``), ``K (T, n, m)`` Kalman gains,
    ``P (T, n, n)`` posterior estimate covariances (``P[t]`` of ``ξ̂_{t+1}``), ``P0 (n, n)``,
    and the :class:`Linearization` they were computed from. The estimated state ``ξ̂`` is
    ``x̂`` (``n = p``, the paper's) or, with ``disturbance=True``, ``(x̂, d̂)``
    (``n = p + q``, :func:`augmented_model`).
    """

    L: np.ndarray
    K: np.ndarray
    P: np.ndarray
    P0: np.ndarray
    lin: Linearization
    disturbance: bool = False

    @property
    def n_steps(self) -> int:
        return int(self.L.shape[0])

    def model(self):
        """``(A, B, H, M, N)`` of the model the filter and LQG-MP use: the linearisation's
        (paper) or :func:`augmented_model` (``disturbance=True``).

        Returns
        -------
        tuple of numpy.ndarray
            ``A (T, n, n)``, ``B (T, n, q)``, ``H (T, m, n)``, ``M (T, n, n)``, ``N (T, m, m)``
            with ``n = p`` (``p + q`` with the disturbance state).
        """
        if self.disturbance:
            return augmented_model(self.lin)
        lin = self.lin
        return lin.A, lin.B, lin.H, lin.M, lin.N


def bryson_weights(state_scale, control_scale) -> tuple[np.ndarray, np.ndarray]:
    """Bryson's rule (Bryson & Ho, *Applied Optimal Control*, 1975, section 5.4).

    ``Q = diag(1 / x_max²)`` and ``R = diag(1 / u_max²)``, so every term of the LQR cost is
    dimensionless and a deviation of one "acceptable" unit costs 1 in any component.

    Parameters
    ----------
    state_scale : array_like
        ``x_max (p,)``, the acceptable deviation of each state component (> 0).
    control_scale : array_like
        ``u_max (q,)``, the acceptable deviation of each control component (> 0).

    Returns
    -------
    Q : numpy.ndarray
        ``(p, p)`` diagonal state cost.
    R : numpy.ndarray
        ``(q, q)`` diagonal control cost.
    """
    xs = as_array(state_scale, "state_scale", shape=(None,))
    us = as_array(control_scale, "control_scale", shape=(None,))
    for name, v in (("state_scale", xs), ("control_scale", us)):
        if not np.all(v > 0):
            raise InvalidInputError(f"{name}: expected positive values, got {v}")
    return np.diag(1.0 / xs**2), np.diag(1.0 / us**2)


def lqg_controller(
    lin: Linearization, Q=None, R=None, Q_final=None, P0=None, *, disturbance: bool = False
) -> LQGController:
    r"""LQR + Kalman gains for ``lin`` (paper IV-C).

    Defaults (explicit ``Q``/``R`` override them): Bryson's rule (:func:`bryson_weights`),
    ``Q = diag(1 / lin.state_scale²)`` and ``R = diag(1 / lin.control_scale²)``, the
    scales the simulator declares (:func:`~riskplan.control.linearize` copies
    ``sim.state_scale`` and the control half-ranges); a component without a declared
    scale gets weight 1 (``Q = I``/``R = I``, the identity costs of van den Berg, Abbeel &
    Goldberg, IJRR 2011, section VII). ``Q_final = Q``, ``P0 = 0`` (the start state is known).

    ``disturbance=True`` (beyond the paper; needs ``linearize(..., disturbance=True)``):
    the state is ``(x̄, d)`` with the constant input disturbance ``d ~ N(0, Σ_d)``
    (:func:`augmented_model`). ``d`` cannot be steered, so the LQR cost is put on what the
    plant receives, ``v_t = ū_t + d``:

    .. math::

        J = \sum_{t<T} (\bar x_t^\top Q \bar x_t + v_t^\top R v_t) + \bar x_T^\top Q_{final}
        \bar x_T, \qquad \bar x_{t+1} = A_t \bar x_t + B_t v_t,

    which is the plain LQR in ``(x̄, v)``: ``v_t = L_t x̄_t``, so ``ū_t = L_t x̄_t − d`` and
    the augmented gain is ``[L_t, −I]`` (the plain gain plus a feed-forward cancelling
    ``B_t d``). The Kalman filter estimates ``(x̄, d)`` on the augmented model from
    ``P0 = diag(P0, Σ_d)`` with the residual process noise ``M^r_t``.

    Parameters
    ----------
    lin : Linearization
        ``A (T, p, p)``, ``B (T, p, q)``, ``M``, ``H``, ``N`` of the plan.
    Q, R, Q_final : array_like, optional
        LQR costs (:func:`~riskplan.control.lqr_gains`); defaults above.
    P0 : array_like, optional
        ``(p, p)`` covariance of the initial estimate (default 0).
    disturbance : bool
        Estimate and cancel a constant input disturbance (beyond the paper).

    Returns
    -------
    LQGController
        Gains ``L``, ``K``, covariances ``P`` and the linearisation.
    """
    if not isinstance(lin, Linearization):
        raise InvalidInputError(f"lin: expected a Linearization, got {type(lin).__name__}")
    if disturbance and lin.disturbance is None:
        raise InvalidInputError(
            "disturbance=True: lin has no disturbance model; linearize it with disturbance=True"
        )
    _T, p, q = lin.B.shape
    if Q is None:
        Q = np.eye(p) if lin.state_scale is None else bryson_weights(lin.state_scale, np.ones(1))[0]
    if R is None:
        R = (
            np.eye(q)
            if lin.control_scale is None
            else bryson_weights(np.ones(1), lin.control_scale)[1]
        )
    Q_final = Q if Q_final is None else Q_final
    P0 = np.zeros((p, p)) if P0 is None else as_array(P0, "P0", shape=(p, p))
    L = lqr_gains(lin.A, lin.B, Q, R, Q_final)
    if not disturbance:
        K, P = kalman_gains(lin.A, lin.H, lin.M, lin.N, P0)
        return LQGController(L=L, K=K, P=P, P0=P0, lin=lin)
    T = L.shape[0]
    r = lin.disturbance.n_bias
    # the bias e moves only the measurement: no feedback on it (its gain is 0)
    L = np.concatenate([L, np.broadcast_to(-np.eye(q), (T, q, q)), np.zeros((T, q, r))], axis=2)
    A, _B, H, M, N = augmented_model(lin)
    P0 = _block_diag(P0, lin.disturbance.cov, lin.disturbance.bias_cov)
    K, P = kalman_gains(A, H, M, N, P0)
    return LQGController(L=L, K=K, P=P, P0=P0, lin=lin, disturbance=True)
