r"""The persistent part of the parameter uncertainty (beyond the deformable-planning paper;
``linearize(..., disturbance=True)``, :mod:`riskplan.control.linearize`).

The draws ``s_i ~ S`` of material, mesh and interaction force hold for a whole execution.
Their one-step deviations along a plan are explained here by least squares over all steps:

* on the state side, one constant input disturbance ``d_i (q,)`` per draw,
  ``x̄_{t+1} = A_t x̄_t + B_t (ū_t + d)`` (:func:`fit_disturbance`);
* on the measurement side, a persistent measurement bias ``b_{i,t} ≈ C_t e_i`` for the
  simulators whose parameters move what is measured (:func:`fit_measurement_bias`).

Both return the prior of the persistent state and the residual noise it leaves; the result
is a :class:`Disturbance`, carried by ``Linearization.disturbance`` into the controller
(:func:`~riskplan.control.lqg_controller` ``disturbance=True``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan.errors import InvalidInputError

__all__ = ["Disturbance", "fit_disturbance", "fit_measurement_bias"]


@dataclass(frozen=True, eq=False)
class Disturbance:
    """The persistent part of the parameter uncertainty as a constant input disturbance
    (:mod:`riskplan.control.linearize`, ``disturbance=True``).

    Attributes
    ----------
    cov : (q, q) ``Σ_d = (1/n) Σ_i d_i d_iᵀ``, the prior of ``d`` (second moment about zero).
    M : (T, p, p) the residual process noise ``M^r_t`` (what ``B_t d_i`` does not explain,
        plus the per-step actuation noise).
    fits : (n, q) the fitted ``d_i``, one row per parameter draw.
    weights : (p,) the state weights ``w`` of the least-squares fit.
    C : (T, m, r) or None, the directions of a persistent *measurement* bias
        ``b_t = C_t e`` with ``e ~ N(0, Σ_e)`` constant (simulators whose parameters move
        the measurement, not the reduced state: the needle in its material frame;
        :func:`fit_measurement_bias`). ``None`` (or ``r = 0``): no bias state.
    bias_cov : (r, r) ``Σ_e`` (None without ``C``).
    N : (T, m, m) or None, the residual measurement noise ``N^r_t`` with the bias state.
    bias_fits : (n, r) or None, the fitted ``e_i``.
    """

    cov: np.ndarray
    M: np.ndarray
    fits: np.ndarray
    weights: np.ndarray
    C: np.ndarray | None = None
    bias_cov: np.ndarray | None = None
    N: np.ndarray | None = None
    bias_fits: np.ndarray | None = None

    def __post_init__(self):
        for name in ("cov", "M", "fits", "weights", "C", "bias_cov", "N", "bias_fits"):
            v = getattr(self, name)
            if v is None:
                continue
            arr = np.array(v, dtype=np.float64, copy=True)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if self.C is not None and (self.bias_cov is None or self.N is None):
            raise InvalidInputError("Disturbance: C needs bias_cov (r, r) and N (T, m, m)")

    @property
    def n_bias(self) -> int:
        """``r``, the dimension of the measurement-bias state (0 without one)."""
        return 0 if self.C is None else int(self.C.shape[2])


def fit_disturbance(B, P, D, weights, rcond: float = 1e-8) -> Disturbance:
    """Least-squares constant input disturbance of each parameter draw (module docstrings).

    Parameters
    ----------
    B : (T, p, q) control matrices along the plan.
    P : (T, n, p) persistent one-step deviations ``p_{i,t}`` of the ``n`` draws.
    D : (T, n, p) full one-step deviations ``δ_{i,t}`` (actuation noise included).
    weights : (p,) state weights ``w`` of the fit.
    rcond : relative cut-off of the singular values of the stacked ``diag(w) B_t``; a
        direction of ``d`` that no ``B_t`` moves gets 0 (minimum-norm solution).

    Returns
    -------
    :class:`Disturbance` with ``d_i = argmin Σ_t ‖diag(w)(p_{i,t} − B_t d)‖²``,
    ``Σ_d = (1/n) Σ_i d_i d_iᵀ`` and ``M^r_t = (1/n) Σ_i r_{i,t} r_{i,t}ᵀ``,
    ``r_{i,t} = δ_{i,t} − B_t d_i``.
    """
    B = np.asarray(B, dtype=np.float64)
    P = np.asarray(P, dtype=np.float64)
    D = np.asarray(D, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    T, p, q = B.shape
    n = P.shape[1]
    G = (w[None, :, None] * B).reshape(T * p, q)
    Y = (w[None, None, :] * P).transpose(0, 2, 1).reshape(T * p, n)
    fits = np.linalg.lstsq(G, Y, rcond=rcond)[0].T  # (n, q)
    R = D - np.einsum("tpq,nq->tnp", B, fits)
    M = np.einsum("tni,tnj->tij", R, R) / n
    return Disturbance(
        cov=fits.T @ fits / n, M=0.5 * (M + np.swapaxes(M, 1, 2)), fits=fits, weights=w
    )


#: share of the draws' squared measurement bias the bias state must explain
#: (:func:`fit_measurement_bias`): the fewest principal directions reaching it are kept
BIAS_ENERGY = 0.99


def fit_measurement_bias(Pb, Bm, N, energy: float = BIAS_ENERGY, max_rank: int | None = None):
    """A persistent measurement bias ``b_{i,t} ≈ C_t e_i`` of the parameter draws (beyond the
    paper; the measurement-side twin of :func:`fit_disturbance`).

    A draw that moves what is *measured* but not the reduced state (the needle in its
    material frame: the tissue's displacement under the robot depends on E, ν and the
    force; the robot's material pose does not) biases every measurement of an execution
    in the same way. With ``c_i = vec_t(Pb[t, i]) (T m,)`` the persistent biases of draw
    ``i`` along the plan, the principal directions of ``Y = [c_1 … c_n]ᵀ = U S Vᵀ`` give

        C_t = V[:, :r] (rows of step t, (m, r)),   e_i = U[i, :r] S[:r],
        Σ_e = (1/n) Σ_i e_i e_iᵀ,   N^r_t = N_t + (1/n) Σ_i (b_{i,t} − C_t e_i)(…)ᵀ

    with ``r`` the fewest directions holding ``energy`` of ``Σ S²`` (at most ``max_rank``).
    ``Bm[t, i]``, the full bias (per-step noise included), fills the residual.

    Parameters
    ----------
    Pb : (T, n, m) persistent biases (without actuation noise).
    Bm : (T, n, m) full biases.
    N : (T, m, m) the sensing noise covariances.
    energy : share of ``Σ S²`` the kept directions hold (default ``BIAS_ENERGY``, 0.99).
    max_rank : at most this many directions (default: the number of draws ``n``).

    Returns
    -------
    ``(C (T, m, r), Σ_e (r, r), N^r (T, m, m), fits (n, r))``; ``r = 0`` when the draws
    do not bias the measurement.
    """
    Pb = np.asarray(Pb, dtype=np.float64)
    Bm = np.asarray(Bm, dtype=np.float64)
    N = np.asarray(N, dtype=np.float64)
    T, n, m = Pb.shape
    Y = Pb.transpose(1, 0, 2).reshape(n, T * m)
    U, S, Vt = np.linalg.svd(Y, full_matrices=False)
    total = float((S**2).sum())
    if total <= 0.0:
        r = 0
    else:
        r = int(np.searchsorted(np.cumsum(S**2) / total, energy) + 1)
        r = min(r, len(S), n if max_rank is None else int(max_rank))
    C = Vt[:r].T.reshape(T, m, r)
    fits = U[:, :r] * S[:r]
    R = Bm - np.einsum("tmr,nr->tnm", C, fits)
    Nr = N + np.einsum("tni,tnj->tij", R, R) / n
    return C, fits.T @ fits / n, 0.5 * (Nr + np.swapaxes(Nr, 1, 2)), fits
