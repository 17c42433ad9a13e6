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

import numpy as np

from riskplan._validation import as_array, check_count
from riskplan.control.disturbance_fit import Disturbance, fit_disturbance, fit_measurement_bias
from riskplan.control.linearize_runs import (
    _callable_prior,
    _fixed_prior,
    _param_draws,
    _run_chunk,
    _Step,
    control_jacobian,
)
from riskplan.control.plan import NominalPlan
from riskplan.errors import InvalidInputError

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
    """The observation model of ``sim``.

    Parameters
    ----------
    sim : Simulator
        The simulator (``observation_matrix``, ``sensing_cov``, ``state_dim``).
    H : numpy.ndarray, optional
        ``(m, p)`` the observation matrix (default ``sim.observation_matrix``).
    N : numpy.ndarray, optional
        ``(m, m)`` the measurement noise covariance (default ``sim.sensing_cov``).

    Returns
    -------
    H : numpy.ndarray
        ``(m, p)``.
    N : numpy.ndarray
        ``(m, m)``.
    """
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

    from riskplan.parallel import spawn_seeds

    a_prior, W_factor, eps, n_a_runs = _checked_arguments(
        sim, plan, W, epsilon, n_samples, n_a_runs, a_prior, rcond
    )
    H0, N0 = observation_model(sim, H, N)
    p, q, T = sim.state_dim, sim.control_dim, plan.n_steps
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
    steps = _run_steps(
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
        backend,
        workers,
    )
    A, B, M, drift, rank = _stacked(steps, plan, a_prior, p, q)
    _warn_rank_deficient(rank, p, q, n_a_runs, a_prior)
    Hs, Ns = _observation_along(steps, H0, N0, p, measuring, len(draws))
    scale = getattr(sim, "state_scale", None)
    dist = None
    if disturbance:
        dist = _disturbance_model(steps, B, N0, scale, len(draws), measuring, float(rcond))
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
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


def _checked_arguments(sim, plan, W, epsilon, n_samples, n_a_runs, a_prior, rcond):
    """The arguments of :func:`linearize`, checked once: ``(a_prior, W_factor (q, q), eps
    (q,), n_a_runs)`` with ``W_factor W_factorᵀ = W`` (defaults filled in)."""
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
    return a_prior, W_factor, eps, n_a_runs


def _run_steps(
    sim,
    plan,
    draws,
    W_factor,
    eps,
    a_prior,
    rcond,
    K,
    step_seeds,
    disturbance,
    measuring,
    backend,
    workers,
) -> list[_Step]:
    """The runs of every step (``riskplan.control.linearize_runs``), in chunks of steps on
    :func:`riskplan.parallel.map_tasks`; returned in step order."""
    from functools import partial

    from riskplan.parallel import chunk_count, map_tasks

    T = plan.n_steps
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
        rcond,
        K,
        step_seeds,
        disturbance,
        measuring,
    )
    results = map_tasks(fn, chunks, backend=backend, workers=workers, chunksize=1)
    per_t = {}
    for chunk, res in zip(chunks, results):
        per_t.update(zip(chunk, res))
    return [per_t[t] for t in range(T)]


def _stacked(steps: list[_Step], plan, a_prior, p: int, q: int):
    """``A (T, p, p)``, ``B (T, p, q)``, ``M (T, p, p)``, ``drift (T, p)``, ``rank (T,)``
    of the steps; ``A_0 = A_1`` (module docstring), the prior if ``T = 1``."""
    T = len(steps)
    A = np.empty((T, p, p))
    B = np.empty((T, p, q))
    M = np.empty((T, p, p))
    rank = np.empty(T, dtype=int)
    drift = np.empty((T, p))
    for t, s in enumerate(steps):
        if s.A is not None:
            A[t] = s.A
        B[t], M[t], drift[t], rank[t] = s.B, s.M, s.drift, s.rank
    if T >= 2:
        A[0], rank[0] = A[1], rank[1]
    else:
        A[0], rank[0] = (
            _callable_prior(a_prior, plan, 0, p) if callable(a_prior) else _fixed_prior(a_prior, p),
            0,
        )
    return A, B, M, drift, rank


def _warn_rank_deficient(rank, p: int, q: int, n_a_runs: int, a_prior) -> None:
    """One :class:`RankDeficiencyWarning` naming the steps whose ``X_t`` has rank < p
    (attributed to the caller of :func:`linearize`)."""
    T = len(rank)
    deficient = [t for t in range(1, T) if rank[t] < p]
    prior_name = "simulator's" if callable(a_prior) else a_prior
    if deficient:
        low = int(rank[deficient].min())
        why = (
            f"expected: one control step excites at most q = {q} directions"
            if low >= min(q, n_a_runs)
            else f"fewer than the q = {q} directions a control step can excite: are controls at their bounds?"
        )
        warnings.warn(
            f"linearize: X_t has rank < p = {p} at steps {deficient[:10]}{' ...' if len(deficient) > 10 else ''} "
            f"(lowest rank {low}; {why}); A_t keeps the {prior_name!r} prior on the unexcited directions",
            RankDeficiencyWarning,
            stacklevel=3,
        )


def _observation_along(steps: list[_Step], H0, N0, p: int, measuring: bool, n_draws: int):
    """``H (T, m, p)`` and ``N (T, m, m)`` along the plan: constant, or with ``measuring``
    ``H_t`` per step and ``N_t`` widened by the draws' measurement biases."""
    T = len(steps)
    m = H0.shape[0]
    Hs = np.broadcast_to(H0, (T, m, p))
    Ns = np.broadcast_to(N0, (T, m, m))
    if measuring:
        Hs = np.stack([s.H for s in steps])
        if n_draws:
            # the paper's zero-mean reading on the measurement side: the draws' spread of
            # what H_t does not explain is measurement noise, as M_t is on the state side
            Bm = np.stack([s.bias for s in steps])
            Ns = N0 + np.einsum("tni,tnj->tij", Bm, Bm) / n_draws
    return Hs, Ns


def _disturbance_model(steps: list[_Step], B, N0, scale, n_draws: int, measuring: bool, rcond):
    """The :class:`~riskplan.control.Disturbance` of the draws (module docstring,
    ``disturbance=True``): zeros without draws."""
    T, p, q = B.shape
    m = N0.shape[0]
    weights = np.ones(p) if scale is None else 1.0 / np.asarray(scale, dtype=np.float64)
    if not n_draws:
        return Disturbance(
            cov=np.zeros((q, q)), M=np.zeros((T, p, p)), fits=np.zeros((0, q)), weights=weights
        )
    dist = fit_disturbance(
        B,
        np.stack([s.P for s in steps]),
        np.stack([s.D for s in steps]),
        weights,
        rcond=rcond,
    )
    if measuring:
        C, Se, Nr, ef = fit_measurement_bias(
            np.stack([s.bias_persistent for s in steps]),
            np.stack([s.bias for s in steps]),
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
    return dist
