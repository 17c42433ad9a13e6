r"""Numerical linearisation of a simulator along a nominal plan (deformable-planning paper,
Patil, van den Berg & Alterovitz, RSS 2011, section IV-B, eq. 4).

Deviation model, ``t = 0 .. T-1`` with ``T = ℓ`` the number of plan steps:

.. math::

    \bar x_{t+1} = A_t \bar x_t + B_t \bar u_t + m_t, \qquad m_t \sim \mathcal N(0, M_t)

    \bar z_{t+1} = H_t \bar x_{t+1} + n_t, \qquad n_t \sim \mathcal N(0, N_t)

with ``x̄_t = x_t − x*_t``, ``ū_t = u_t − u*_t``; ``H[t]`` is the observation matrix of the
measurement taken after step ``t`` (the same indexing as :func:`~riskplan.control.kalman_gains`).

Estimation, per step ``t`` (each run restarts the simulator from a stored plan state):

* ``A_t`` (paper "Numerical estimation of matrix A_t"): the state cannot be perturbed
  directly, so ``K`` runs apply ``u*_{t-1} + w_k``, ``w_k ~ N(0, W)``, from ``y*_{t-1}``
  (giving ``x*_t + x̄^k_t``), then ``u*_t`` (giving ``x*_{t+1} + x̄^k_{t+1}``). With the
  deviations as columns of ``X_t (p, K)`` and ``X_{t+1} (p, K)``,

  .. math:: A_t = A_{\mathrm{prior}} + (X_{t+1} - A_{\mathrm{prior}} X_t)\, X_t^{+}

  (``X_t⁺`` the Moore–Penrose pseudo-inverse, singular values below ``rcond · σ_max``
  dropped). With ``a_prior="zero"`` this is the paper's ``A_t = X_{t+1} X_t⁺``; the default
  ``a_prior="identity"`` differs from it only where ``X_t`` is rank deficient: directions
  the runs cannot excite keep ``A = I`` (the deviation persists, as the lateral offset of a
  car does) instead of being mapped to zero. A simulator that knows the structure of its
  ``A_t`` declares it as a callable prior evaluated at ``y*_{t+1}`` (the manipulation:
  ``[[0, J], [0, I]]``, positions following the applied forces); the runs then correct it
  on the ``q`` leading singular directions of ``X_t`` only (the first-order subspace, see
  ``K`` below: beyond it ``X_t`` holds second-order parts, and their pseudo-inverse would
  overwrite the exact prior with curvature divided by tiny singular values). A rank-deficient ``X_t`` is reported once
  per call with a :class:`RankDeficiencyWarning` naming the steps.
  ``w_k`` components that would leave the control bounds are mirrored (``−w``) and then
  clipped. Step ``t = 0`` has no earlier control to perturb; the start state is known
  exactly (``x̄_0 = 0``), so ``A_0`` only multiplies a zero deviation, and we set
  ``A_0 = A_1`` (``A_prior`` if ``T = 1``).

  ``K``: the paper takes ``K = 2p``; our default is ``K = 2 min(p, q)``. The deviations
  come from perturbing the ``q``-dimensional control, so to first order
  ``X_t = J_t [w_1 … w_K]`` with ``J_t = ∂x_t/∂u_{t-1} (p, q)``: ``rank X_t ≤ q`` whatever
  ``K``, and the fit ``A_t`` acts on the same ``q``-dimensional subspace (the prior fills
  the rest) for every ``K > q``; more runs only average the second-order (curvature) part
  of the deviations. ``K = 2q`` keeps twice the runs the subspace needs. Checked on a
  linear system (the same ``A_t`` for ``K = 2q`` and ``2p``, to rounding). On the
  manipulation scenario (``p = 32``, ``q = 6``) the runs excite the six directions
  ``[J_t; I] w`` and the simulator's prior supplies the other 26 (tests check ``A_t``
  against finite differences of the step). ``n_a_runs=2 * sim.state_dim`` restores the
  paper's. A simulator may declare ``a_max_rank`` (an int): at most that many singular
  directions of ``X_t`` are fitted (the needle: 2, its control dimension; the deviations beyond
  the first-order span are second order, and inverting their tiny singular values gave LQR
  gains of 10⁵).
* ``B_t``: ``q`` runs from ``y*_t`` with ``u*_t + ε_j e_j``; column ``j`` is
  ``(x^j_{t+1} − x*_{t+1}) / ε_j`` (forward difference; ``ε_j → −ε_j`` at an upper bound).
  Default ``ε_j = 10⁻³ (high_j − low_j)``.
* ``M_t``: ``n_samples`` draws ``s_i ~ S`` (the same draws at every step, so FEM models
  stay cached), one run each from ``y*_t`` with ``u*_t``; ``M_t = (1/n) Σ_i d_i d_iᵀ`` with
  ``d_i = x^i_{t+1} − x*_{t+1}``, the second moment about zero: the model's noise is
  zero-mean, so a systematic shift under S counts as spread (conservative). A draw on
  another mesh than the plan's (mesh case) is run on the plan's mesh, since a stored state
  cannot change mesh: mesh uncertainty enters ``M_t`` only through execution, not here.
  The mean ``d̄_t`` of the ``d_i`` is kept as ``Linearization.drift`` (beyond the paper).
* ``H_t``, ``N_t``: ``sim.observation_matrix`` and ``sim.sensing_cov`` (constant), or the
  ``H``/``N`` arguments.

Persistent disturbance (beyond the paper; ``disturbance=True``). The draws ``s_i ~ S`` of
material, mesh and interaction force hold for a whole execution, but ``M_t`` treats their
effect as fresh noise at every step. With ``disturbance=True`` each draw's one-step
deviations along the plan are also explained by one constant input disturbance
``d_i (q,)``, ``x̄_{t+1} = A_t x̄_t + B_t (ū_t + d)``, fitted by weighted least squares
over all steps (``w = 1 / sim.state_scale`` where the simulator declares it, else 1):

    d_i = argmin_d Σ_t ‖diag(w) (p_{i,t} − B_t d)‖²

where ``p_{i,t}`` is the deviation of draw ``i`` *without* its actuation noise (the
persistent part; a draw whose only difference from the plan's parameters is actuation noise
has ``p_{i,t} = 0`` without a run, any other draw with actuation noise is run once more with
the noise switched off). Then ``Σ_d = (1/n) Σ_i d_i d_iᵀ`` (second moment about zero, as
``M_t``: the plan is made with the expected parameters, so a mean offset is an offset the
filter has to find) and the residual noise, what ``d`` cannot explain plus the per-step
actuation noise,

    M^r_t = (1/n) Σ_i (δ_{i,t} − B_t d_i)(δ_{i,t} − B_t d_i)ᵀ

with ``δ_{i,t}`` the full deviation (actuation noise included). Both are returned in
``Linearization.disturbance`` (:class:`Disturbance`); ``A``, ``B``, ``M`` stay the
paper's, bit for bit, so one linearisation serves both controllers
(:func:`~riskplan.control.lqg_controller` ``disturbance=True``).

Simulators with a ``step_near(state, control, params, near)`` method (the manipulation
scenario: a quasi-static solve whose answer depends only on the applied forces) get the
nominal state the run is expected to land near (``y*_t`` for the first A-run step,
``y*_{t+1}`` for the others) as the solver's start; the result is ``step``'s up to the
solver tolerance, in a fraction of the Newton iterations.

Steps are independent; they run in chunks on :func:`riskplan.parallel.map_tasks` with one
seed per step from :func:`riskplan.parallel.spawn_seeds`, so the result does not depend
on the backend or the number of workers.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import partial

import numpy as np

from riskplan._validation import as_array, as_generator, check_count
from riskplan.control.plan import NominalPlan
from riskplan.errors import InvalidInputError, SimulationError

__all__ = [
    "Disturbance",
    "Linearization",
    "RankDeficiencyWarning",
    "control_jacobian",
    "fit_disturbance",
    "fit_measurement_bias",
    "linearize",
    "observation_model",
]

A_PRIORS = ("identity", "zero")


class RankDeficiencyWarning(RuntimeWarning):
    """The deviations ``X_t`` of the A-estimation runs do not span the reduced state space."""


@dataclass(frozen=True, eq=False)
class Disturbance:
    """The persistent part of the parameter uncertainty as a constant input disturbance
    (module docstring, ``disturbance=True``).

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


@dataclass(frozen=True, eq=False)
class Linearization:
    """The linear(ised) deviation model of a plan (module docstring for the indexing).

    Attributes
    ----------
    A : (T, p, p)
    B : (T, p, q)
    M : (T, p, p) process noise covariances (zeros without a parameter distribution).
    H : (T, m, p) observation matrices, ``H[t]`` observes ``x̄_{t+1}``.
    N : (T, m, m) measurement noise covariances.
    rank : (T,) int, numerical rank of ``X_t`` (``A_0`` copies step 1, so ``rank[0]`` does too).
    drift : (T, p) mean ``(1/n) Σ_i d_i`` of the one-step deviations under S (zeros without
        draws). The paper's model is zero-mean (``M_t`` is the second moment about zero);
        :func:`~riskplan.control.lqgmp` can carry this mean (``drift=True``).
    state_scale : (p,) or None, acceptable deviation of each component of x
        (``sim.state_scale`` where the simulator declares it).
    control_scale : (q,) or None, acceptable deviation of each control component (the
        half-range of ``sim.control_bounds``). Both set the default Bryson weights of
        :func:`~riskplan.control.lqg_controller`.
    disturbance : :class:`Disturbance` or None, the constant-disturbance model of the
        parameter draws (``linearize(..., disturbance=True)``; beyond the paper).
    """

    A: np.ndarray
    B: np.ndarray
    M: np.ndarray
    H: np.ndarray
    N: np.ndarray
    rank: np.ndarray
    drift: np.ndarray | None = None
    state_scale: np.ndarray | None = None
    control_scale: np.ndarray | None = None
    disturbance: Disturbance | None = None

    def __post_init__(self):
        if self.disturbance is not None and not isinstance(self.disturbance, Disturbance):
            raise InvalidInputError(
                f"disturbance: expected a Disturbance or None, got {type(self.disturbance).__name__}"
            )
        if self.drift is None:
            object.__setattr__(self, "drift", np.zeros(self.A.shape[:2]))
        _, p, q = np.shape(self.B)
        for name, n in (("state_scale", p), ("control_scale", q)):
            v = getattr(self, name)
            if v is not None:
                v = as_array(v, name, shape=(n,))
                if not np.all(v > 0):
                    raise InvalidInputError(f"{name}: expected positive values, got {v}")
                v.setflags(write=False)
                object.__setattr__(self, name, v)
        for name in ("A", "B", "M", "H", "N", "rank", "drift"):
            arr = np.array(getattr(self, name), copy=True)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def n_steps(self) -> int:
        return int(self.A.shape[0])


def observation_model(sim, H=None, N=None) -> tuple[np.ndarray, np.ndarray]:
    """``H (m, p)`` and ``N (m, m)`` from the arguments or ``sim.observation_matrix`` / ``sim.sensing_cov``."""
    if H is None:
        H = getattr(sim, "observation_matrix", None)
    if N is None:
        N = getattr(sim, "sensing_cov", None)
    if H is None or N is None:
        raise InvalidInputError(
            "H, N: the simulator has no observation_matrix / sensing_cov attribute; pass H (m, p) and N (m, m)"
        )
    H = as_array(H, "H", shape=(None, sim.state_dim))
    N = as_array(N, "N", shape=(H.shape[0], H.shape[0]))
    return H, N


def _checked(sim, state, t: int, what: str) -> np.ndarray:
    x = np.asarray(sim.reduced(state), dtype=np.float64)
    if not np.all(np.isfinite(x)):
        raise SimulationError(f"linearize: non-finite reduced state at step {t} ({what})")
    return x


def _finite(X: np.ndarray, t: int, what: str) -> None:
    if not np.isfinite(X).all():
        raise SimulationError(f"linearize: non-finite reduced state at step {t} ({what})")


def _mirror(u: np.ndarray, w: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    v = u + w
    out = (v < bounds[:, 0]) | (v > bounds[:, 1])
    v = np.where(out, u - w, v)
    return np.clip(v, bounds[:, 0], bounds[:, 1])


def _fixed_prior(a_prior: str, p: int) -> np.ndarray:
    return np.eye(p) if a_prior == "identity" else np.zeros((p, p))


def _callable_prior(a_prior, plan: NominalPlan, t: int, p: int) -> np.ndarray:
    """``a_prior(y*_{t+1}, params) (p, p)``: a simulator's own structure of ``A_t``."""
    prior = np.asarray(a_prior(plan.states[t + 1], plan.params), dtype=np.float64)
    if prior.shape != (p, p) or not np.all(np.isfinite(prior)):
        raise InvalidInputError(
            f"a_prior: expected a finite ({p}, {p}) matrix from the callable, got shape {prior.shape}"
        )
    return prior


def _stepper(sim):
    """``run(state, u, params, near)``: ``sim.step_near`` where the simulator has one (its
    solver starts from ``near``, a state expected close to the result), else ``sim.step``."""
    step_near = getattr(sim, "step_near", None)
    if step_near is None:
        return lambda state, u, params, near: sim.step(state, u, params)
    return step_near


def control_jacobian(
    sim, state, control, params, epsilon, x_next=None, t: int = 0, near=None
) -> np.ndarray:
    """``B (p, q)``: forward differences of ``sim.reduced(sim.step(state, u, params))`` in ``u``.

    ``epsilon (q,)`` per component (sign flipped where ``u + ε`` leaves the upper bound);
    ``x_next (p,)`` is the unperturbed result (computed if not given); ``near``: the
    unperturbed next state, the solver's start for simulators with ``step_near``. Paper
    IV-B, ``B_t``.
    """
    run = _stepper(sim)
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    u = np.asarray(control, dtype=np.float64)
    if x_next is None:
        x_next = _checked(sim, run(state, u, params, near), t + 1, "nominal control")
    eps = np.asarray(epsilon, dtype=np.float64)
    q = u.shape[0]
    B = np.empty((x_next.shape[0], q))
    for j in range(q):
        e = eps[j] if u[j] + eps[j] <= bounds[j, 1] else -eps[j]
        du = u.copy()
        du[j] += e
        B[:, j] = (
            _checked(sim, run(state, du, params, near), t + 1, f"control component {j} perturbed")
            - x_next
        ) / e
    return B


def _persistent(params, plan_params):
    """``params`` without its actuation noise, or ``None`` if that is the plan's own
    parameters (then the persistent deviation is zero without a run)."""
    quiet = params.replace(actuation_cov=None, actuation_seed=plan_params.actuation_seed)
    return None if quiet == plan_params else quiet


def _draw_state(sim, run, plan: NominalPlan, t: int, s_i):
    """Full state after ``u*_t`` from ``y*_t`` under the draw ``s_i``; a draw on another
    mesh (only with ``sim.transfer_state``) runs on its own mesh."""
    y_t = plan.states[t]
    if s_i.n_elements != plan.params.n_elements:
        y_i = sim.transfer_state(y_t, s_i)
        return run(y_i, plan.controls[t], s_i, None)
    return run(y_t, plan.controls[t], s_i, plan.states[t + 1])


def _draw_step(sim, run, plan: NominalPlan, t: int, s_i) -> np.ndarray:
    """Reduced state after ``u*_t`` from ``y*_t`` under the draw ``s_i``."""
    return sim.reduced(_draw_state(sim, run, plan, t, s_i))


def _measured(sim, state) -> np.ndarray:
    return np.asarray(sim.measure(state, noise=np.zeros(sim.obs_dim)), dtype=np.float64)


def _steps(
    sim,
    plan: NominalPlan,
    draws,
    W_factor,
    eps,
    a_prior,
    rcond,
    K,
    seeds,
    ts,
    disturbance=False,
    measuring=False,
) -> list:
    """(A_t or None, B_t, M_t, drift_t, rank_t, D_t, P_t, H_t, b_t, c_t) for each t in
    ``ts``; ``D_t (n, p)`` the draws' deviations and ``P_t (n, p)`` those without actuation
    noise (both ``None`` unless ``disturbance``). With ``measuring`` (a simulator with
    ``observation_jacobian`` and ``measure``): ``H_t (m, p)`` at ``y*_{t+1}``, the draws'
    measurement biases ``b_t (n, m)`` (the part of ``measure(y^i_{t+1}) − measure(y*_{t+1})``
    that ``H_t`` does not explain) and ``c_t (n, m)`` those without actuation noise
    (``None`` unless ``disturbance``); else ``None``."""
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    params = plan.params
    p = plan.reduced.shape[1]
    fixed = None if callable(a_prior) else _fixed_prior(a_prior, p)
    max_rank = getattr(sim, "a_max_rank", None)
    run = _stepper(sim)
    out = []
    for t, seed in zip(ts, seeds):
        prior = fixed if fixed is not None else _callable_prior(a_prior, plan, t, p)
        y_t = plan.states[t]
        u_t = plan.controls[t]
        x_next = plan.reduced[t + 1]
        A = None
        rank = -1
        if t >= 1:
            gen = np.random.default_rng(seed)
            y_prev, u_prev = plan.states[t - 1], plan.controls[t - 1]
            Z = gen.standard_normal((K, W_factor.shape[1])) @ W_factor.T
            X0 = np.empty((p, K))
            X1 = np.empty((p, K))
            for k in range(K):
                yk = run(y_prev, _mirror(u_prev, Z[k], bounds), params, y_t)
                X0[:, k] = sim.reduced(yk)
                X1[:, k] = sim.reduced(run(yk, u_t, params, plan.states[t + 1]))
            _finite(X0, t, "A runs")
            _finite(X1, t + 1, "A runs")
            X0 -= plan.reduced[t][:, None]
            X1 -= x_next[:, None]
            U, s, Vt = np.linalg.svd(X0, full_matrices=False)
            keep = s > rcond * (s[0] if s.size and s[0] > 0 else 1.0)
            if fixed is None:
                # a declared (exact) prior: fit only the q first-order directions; beyond
                # them X_t holds second-order parts, whose pseudo-inverse would replace the
                # exact prior by a fit of curvature divided by tiny singular values
                keep[W_factor.shape[0] :] = False
            if max_rank is not None:
                keep[max_rank:] = False  # singular values are sorted: keep the largest
            rank = int(keep.sum())
            if rank == 0:
                A = prior.copy()
            else:
                pinv = (Vt[keep].T / s[keep]) @ U[:, keep].T  # (K, p)
                A = prior + (X1 - prior @ X0) @ pinv
        B = control_jacobian(
            sim, y_t, u_t, params, eps, x_next=x_next, t=t, near=plan.states[t + 1]
        )
        M = np.zeros((p, p))
        drift = np.zeros(p)
        D = Pd = Ht = Bm = Pb = None
        if measuring:
            Ht = np.asarray(sim.observation_jacobian(plan.states[t + 1], params), dtype=np.float64)
            z_next = _measured(sim, plan.states[t + 1])
        if draws:
            D = np.empty((len(draws), p))
            Y = []
            for i, s_i in enumerate(draws):
                y_i = _draw_state(sim, run, plan, t, s_i)
                D[i] = sim.reduced(y_i)
                if measuring:
                    Y.append(_measured(sim, y_i))
            _finite(D, t + 1, "parameter draws")
            D -= x_next
            M = D.T @ D / len(draws)
            drift = D.mean(axis=0)
            if measuring:
                Bm = np.asarray(Y) - z_next - D @ Ht.T
                _finite(Bm, t + 1, "measurements of the parameter draws")
            if disturbance:
                Pd = D.copy()
                Pb = None if Bm is None else Bm.copy()
                for i, s_i in enumerate(draws):
                    if s_i.actuation_cov is None:
                        continue  # no per-step part: the persistent deviation is D[i]
                    quiet = _persistent(s_i, params)
                    if quiet is None:
                        Pd[i] = 0.0
                        if Pb is not None:
                            Pb[i] = 0.0
                        continue
                    y_q = _draw_state(sim, run, plan, t, quiet)
                    Pd[i] = sim.reduced(y_q) - x_next
                    if Pb is not None:
                        Pb[i] = _measured(sim, y_q) - z_next - Ht @ Pd[i]
                _finite(Pd, t + 1, "parameter draws without actuation noise")
        out.append((A, B, M, drift, rank, D, Pd, Ht, Bm, Pb))
    return out


def fit_disturbance(B, P, D, weights, rcond: float = 1e-8) -> Disturbance:
    """Least-squares constant input disturbance of each parameter draw (module docstring).

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


def _param_draws(sim, plan: NominalPlan, params_distribution, n_samples: int, seed) -> list:
    if params_distribution is None:
        params_distribution = getattr(sim, "distribution", None)
    if params_distribution is None or n_samples == 0:
        return []
    if isinstance(params_distribution, (list, tuple)):
        draws = list(params_distribution)
    elif hasattr(params_distribution, "sample_many"):
        draws = params_distribution.sample_many(n_samples, seed)
    elif hasattr(params_distribution, "sample"):
        gen = as_generator(seed)
        draws = [params_distribution.sample(gen) for _ in range(n_samples)]
    else:
        raise InvalidInputError(
            f"params_distribution: expected a distribution with sample_many/sample or a list of SimParams, "
            f"got {type(params_distribution).__name__}"
        )
    if callable(getattr(sim, "transfer_state", None)):
        return list(draws)  # mesh draws run on their own meshes (_steps)
    n_el = plan.params.n_elements
    return [d if d.n_elements == n_el else d.replace(n_elements=n_el) for d in draws]


def linearize(
    sim,
    plan: NominalPlan,
    params_distribution=None,
    *,
    W=None,
    epsilon=None,
    n_samples: int = 16,
    n_a_runs: int | None = None,
    a_prior: str | None = None,
    rcond: float = 1e-8,
    H=None,
    N=None,
    seed=None,
    backend: str = "serial",
    workers: int | None = None,
    disturbance: bool = False,
) -> Linearization:
    """Linearise ``sim`` along ``plan`` (paper IV-B; see the module docstring for the method).

    Parameters
    ----------
    sim : a :class:`~riskplan.scenarios.base.Simulator`.
    plan : the :class:`~riskplan.control.NominalPlan` (its ``params`` are used for A and B runs).
    params_distribution : S for ``M_t``: an object with ``sample_many(n, seed)`` (the
        :mod:`riskplan.scenarios.uncertainty` cases), or a list of SimParams, or ``None`` for
        ``sim.distribution`` (``M = 0`` if that is ``None`` too).
    W : (q, q) covariance of the control perturbations for ``A_t``; default
        ``diag((0.01 (high − low))²)``.
    epsilon : scalar or (q,) perturbation for ``B_t``; default ``10⁻³ (high − low)``.
    n_samples : parameter draws for ``M_t`` (ignored for an explicit list).
    n_a_runs : K, runs per step for ``A_t``; default ``2 min(p, q)``. One control step
        excites at most ``q`` directions to first order (rank ``X_t <= q``), so ``K = 2q``
        keeps the information of the paper's ``K = 2p`` at a fraction of the cost for
        ``p >> q`` (manipulation: p = 26, q = 6; module docstring). ``2 * sim.state_dim``
        is the paper's choice.
    a_prior : ``"identity"``, ``"zero"`` (the paper's plain pseudo-inverse) or a callable
        ``a_prior(y*_{t+1}, params) -> (p, p)``, the simulator's exact structure of ``A_t``
        at the plan's next state; ``None`` (default): the simulator's own ``a_prior``
        attribute or method if it declares one, else ``"identity"``.
        :class:`~riskplan.scenarios.manipulation.ManipulationScenario` declares a method:
        ``A = [[0, J], [0, I]]`` (positions follow the applied forces, force deviations
        persist), so the directions the runs cannot excite get their exact value.
    rcond : relative cut-off of the singular values of ``X_t``.
    H, N : observation model override, ``(m, p)`` and ``(m, m)``.
    seed : seeds the perturbations and the parameter draws.
    backend, workers : :func:`riskplan.parallel.map_tasks` over chunks of steps.
    disturbance : also fit each draw's effect as a constant input disturbance (beyond the
        paper, module docstring): ``Linearization.disturbance`` holds ``Σ_d (q, q)``, the
        residual process noise ``M^r (T, p, p)`` and the fits ``(n, q)``. ``A``, ``B``,
        ``M`` are unchanged. Needs parameter draws (``n_samples >= 1`` and a distribution);
        without them ``Σ_d = 0`` and ``M^r = M = 0``.

    Returns
    -------
    :class:`Linearization` with ``A (T, p, p)``, ``B (T, p, q)``, ``M (T, p, p)``,
    ``H (T, m, p)``, ``N (T, m, m)`` (and ``disturbance`` with ``disturbance=True``). Raises :class:`~riskplan.errors.SimulationError` naming
    the step when the simulator returns a non-finite state.
    """
    from riskplan.parallel import chunk_count, map_tasks, spawn_seeds

    if not isinstance(plan, NominalPlan):
        raise InvalidInputError(f"plan: expected a NominalPlan, got {type(plan).__name__}")
    if a_prior is None:
        a_prior = getattr(sim, "a_prior", "identity")
    if not callable(a_prior) and a_prior not in A_PRIORS:
        raise InvalidInputError(
            f"a_prior: expected one of {A_PRIORS} or a callable, got {a_prior!r}"
        )
    if not (0.0 <= float(rcond) < 1.0):
        raise InvalidInputError(f"rcond: expected a number in [0, 1), got {rcond!r}")
    p, q = sim.state_dim, sim.control_dim
    T = plan.n_steps
    if plan.reduced.shape[1] != p or plan.controls.shape[1] != q:
        raise InvalidInputError(
            f"plan: reduced/controls have {plan.reduced.shape[1]}/{plan.controls.shape[1]} columns, simulator p={p}, q={q}"
        )
    if T < 1:
        raise InvalidInputError("plan: expected at least one control")
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    span = bounds[:, 1] - bounds[:, 0]
    if W is None:
        W = np.diag((0.01 * span) ** 2)
    W = as_array(W, "W", shape=(q, q))
    if not np.allclose(W, W.T) or np.linalg.eigvalsh(W).min() < 0 or not np.any(W):
        raise InvalidInputError(
            "W: expected a non-zero symmetric positive semi-definite (q, q) matrix"
        )
    w, v = np.linalg.eigh(W)
    W_factor = v * np.sqrt(np.clip(w, 0.0, None))
    eps = (
        1e-3 * span
        if epsilon is None
        else np.broadcast_to(as_array(epsilon, "epsilon"), (q,)).copy()
    )
    if np.any(eps <= 0):
        raise InvalidInputError(f"epsilon: expected > 0, got {eps}")
    n_a_runs = 2 * min(p, q) if n_a_runs is None else n_a_runs
    n_a_runs = check_count(n_a_runs, "n_a_runs", 1, integral=True)
    check_count(n_samples, "n_samples", 0, integral=True)
    H0, N0 = observation_model(sim, H, N)

    master = int(seed.integers(2**63)) if isinstance(seed, np.random.Generator) else seed
    step_seeds = spawn_seeds(master, T + 1)
    draws = _param_draws(sim, plan, params_distribution, int(n_samples), step_seeds[T])

    # a measurement that depends on the full state (the needle in its material frame):
    # H_t per step and the draws' measurement biases; an explicit H keeps the constant one
    measuring = (
        H is None
        and callable(getattr(sim, "observation_jacobian", None))
        and callable(getattr(sim, "measure", None))
    )
    ts = list(range(T))
    n_chunks = chunk_count(T, backend, workers)
    chunks = [ts[k::n_chunks] for k in range(n_chunks)]
    fn = partial(
        _run_chunk,
        sim,
        plan,
        draws,
        W_factor,
        eps,
        a_prior,
        float(rcond),
        n_a_runs,
        step_seeds,
        bool(disturbance),
        measuring,
    )
    results = map_tasks(fn, chunks, backend=backend, workers=workers, chunksize=1)
    per_t = {}
    for chunk, res in zip(chunks, results):
        per_t.update(zip(chunk, res))

    A = np.empty((T, p, p))
    B = np.empty((T, p, q))
    M = np.empty((T, p, p))
    rank = np.empty(T, dtype=int)
    drift = np.empty((T, p))
    for t in range(T):
        a, b, m_, dr, r = per_t[t][:5]
        if a is not None:
            A[t] = a
        B[t], M[t], drift[t], rank[t] = b, m_, dr, r
    if T >= 2:
        A[0], rank[0] = A[1], rank[1]
    else:
        A[0], rank[0] = (
            _callable_prior(a_prior, plan, 0, p) if callable(a_prior) else _fixed_prior(a_prior, p),
            0,
        )
    deficient = [t for t in range(1, T) if rank[t] < p]
    prior_name = "simulator's" if callable(a_prior) else a_prior
    if deficient:
        low = int(rank[deficient].min())
        q = B.shape[2]
        why = (
            f"expected: one control step excites at most q = {q} directions"
            if low >= min(q, n_a_runs)
            else f"fewer than the q = {q} directions a control step can excite: are controls at their bounds?"
        )
        warnings.warn(
            f"linearize: X_t has rank < p = {p} at steps {deficient[:10]}{' ...' if len(deficient) > 10 else ''} "
            f"(lowest rank {low}; {why}); A_t keeps the {prior_name!r} prior on the unexcited directions",
            RankDeficiencyWarning,
            stacklevel=2,
        )
    m = H0.shape[0]
    Hs = np.broadcast_to(H0, (T, m, p))
    Ns = np.broadcast_to(N0, (T, m, m))
    if measuring:
        Hs = np.stack([per_t[t][7] for t in range(T)])
        if draws:
            # the paper's zero-mean reading on the measurement side: the draws' spread of
            # what H_t does not explain is measurement noise, as M_t is on the state side
            Bm = np.stack([per_t[t][8] for t in range(T)])
            Ns = N0 + np.einsum("tni,tnj->tij", Bm, Bm) / len(draws)
    scale = getattr(sim, "state_scale", None)
    dist = None
    if disturbance:
        weights = np.ones(p) if scale is None else 1.0 / np.asarray(scale, dtype=np.float64)
        if draws:
            dist = fit_disturbance(
                B,
                np.stack([per_t[t][6] for t in range(T)]),
                np.stack([per_t[t][5] for t in range(T)]),
                weights,
                rcond=float(rcond),
            )
            if measuring:
                C, Se, Nr, ef = fit_measurement_bias(
                    np.stack([per_t[t][9] for t in range(T)]),
                    np.stack([per_t[t][8] for t in range(T)]),
                    np.broadcast_to(N0, (T, m, m)),
                )
                if C.shape[2]:
                    dist = Disturbance(
                        cov=dist.cov,
                        M=dist.M,
                        fits=dist.fits,
                        weights=dist.weights,
                        C=C,
                        bias_cov=Se,
                        N=Nr,
                        bias_fits=ef,
                    )
        else:
            dist = Disturbance(
                cov=np.zeros((q, q)), M=np.zeros((T, p, p)), fits=np.zeros((0, q)), weights=weights
            )
    return Linearization(
        A=A,
        B=B,
        M=M,
        H=Hs,
        N=Ns,
        rank=rank,
        drift=drift,
        state_scale=None if scale is None else np.array(scale, dtype=np.float64),
        control_scale=0.5 * (bounds[:, 1] - bounds[:, 0]),
        disturbance=dist,
    )


def _run_chunk(
    sim, plan, draws, W_factor, eps, a_prior, rcond, K, step_seeds, disturbance, measuring, ts
):
    return _steps(
        sim,
        plan,
        draws,
        W_factor,
        eps,
        a_prior,
        rcond,
        K,
        [step_seeds[t] for t in ts],
        ts,
        disturbance,
        measuring,
    )
