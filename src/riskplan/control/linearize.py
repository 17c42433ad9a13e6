"""Numerical linearisation of a simulator along a nominal plan (deformable-planning paper,
Patil, van den Berg & Alterovitz, RSS 2011, section IV-B, eq. 4).

Deviation model, ``t = 0 .. T-1`` with ``T = ℓ`` the number of plan steps:

    x̄_{t+1} = A_t x̄_t + B_t ū_t + m_t,      m_t ~ N(0, M_t)
    z̄_{t+1} = H_t x̄_{t+1} + n_t,           n_t ~ N(0, N_t)

with ``x̄_t = x_t − x*_t``, ``ū_t = u_t − u*_t``; ``H[t]`` is the observation matrix of the
measurement taken after step ``t`` (the same indexing as :func:`~riskplan.control.kalman_gains`).

Estimation, per step ``t`` (each run restarts the simulator from a stored plan state):

* ``A_t`` (paper "Numerical estimation of matrix A_t"): the state cannot be perturbed
  directly, so ``K`` runs apply ``u*_{t-1} + w_k``, ``w_k ~ N(0, W)``, from ``y*_{t-1}``
  (giving ``x*_t + x̄^k_t``), then ``u*_t`` (giving ``x*_{t+1} + x̄^k_{t+1}``). With the
  deviations as columns of ``X_t (p, K)`` and ``X_{t+1} (p, K)``,

      A_t = A_prior + (X_{t+1} − A_prior X_t) X_t⁺

  (``X_t⁺`` the Moore–Penrose pseudo-inverse, singular values below ``rcond · σ_max``
  dropped). With ``a_prior="zero"`` this is the paper's ``A_t = X_{t+1} X_t⁺``; the default
  ``a_prior="identity"`` differs from it only where ``X_t`` is rank deficient: directions
  the runs cannot excite keep ``A = I`` (the deviation persists, as the lateral offset of a
  car does) instead of being mapped to zero. A rank-deficient ``X_t`` is reported once
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
  linear system (the same ``A_t`` for ``K = 2q`` and ``2p``, to rounding) and on the
  manipulation scenario (``p = 26``, ``q = 6``): ``B_t`` and ``M_t`` do not use the
  A-runs; both ``K = 12`` and ``K = 52`` give ``A_t B_{t-1} ≈ 0`` (the new equilibrium
  forgets the previous force); they differ off that subspace (with 52 runs the
  second-order part lifts ``X_t`` to full numerical rank and ``A_t ≈ 0``; with 12 the
  prior stays on 14 directions), and the LQG-MP ``P(success)`` of the two differs by less
  than that of ``K = 52`` under another seed (docs/planning.md).
  ``n_a_runs=2 * sim.state_dim`` restores the paper's. A simulator may declare
  ``a_max_rank`` (an int): at most that many singular directions of ``X_t`` are fitted
  (the needle: 2, its control dimension; the deviations beyond the first-order span are
  second order, and inverting their tiny singular values gave LQR gains of 10⁵).
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

from riskplan._validation import as_array, as_generator
from riskplan.control.plan import NominalPlan
from riskplan.errors import InvalidInputError, SimulationError

__all__ = [
    "Linearization",
    "RankDeficiencyWarning",
    "control_jacobian",
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

    def __post_init__(self):
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


def _steps(sim, plan: NominalPlan, draws, W_factor, eps, a_prior, rcond, K, seeds, ts) -> list:
    """(A_t or None, B_t, M_t, rank_t) for each t in ``ts``."""
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    params = plan.params
    p = plan.reduced.shape[1]
    prior = np.eye(p) if a_prior == "identity" else np.zeros((p, p))
    max_rank = getattr(sim, "a_max_rank", None)
    run = _stepper(sim)
    out = []
    for t, seed in zip(ts, seeds):
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
        if draws:
            D = np.empty((len(draws), p))
            for i, s_i in enumerate(draws):
                if s_i.n_elements != params.n_elements:  # only with sim.transfer_state
                    y_i = sim.transfer_state(y_t, s_i)
                    D[i] = sim.reduced(run(y_i, u_t, s_i, None))
                else:
                    D[i] = sim.reduced(run(y_t, u_t, s_i, plan.states[t + 1]))
            _finite(D, t + 1, "parameter draws")
            D -= x_next
            M = D.T @ D / len(draws)
            drift = D.mean(axis=0)
        out.append((A, B, M, drift, rank))
    return out


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
    a_prior : ``"identity"`` or ``"zero"`` (the paper's plain pseudo-inverse); ``None``
        (default): the simulator's own ``a_prior`` attribute if it declares one, else
        ``"identity"``. A quasi-static simulator, whose next state does not depend on the
        previous one (:class:`~riskplan.scenarios.manipulation.ManipulationScenario`),
        declares ``"zero"``: its exact ``A`` is 0 in every direction, excited or not.
    rcond : relative cut-off of the singular values of ``X_t``.
    H, N : observation model override, ``(m, p)`` and ``(m, m)``.
    seed : seeds the perturbations and the parameter draws.
    backend, workers : :func:`riskplan.parallel.map_tasks` over chunks of steps.

    Returns
    -------
    :class:`Linearization` with ``A (T, p, p)``, ``B (T, p, q)``, ``M (T, p, p)``,
    ``H (T, m, p)``, ``N (T, m, m)``. Raises :class:`~riskplan.errors.SimulationError` naming
    the step when the simulator returns a non-finite state.
    """
    from riskplan.parallel import map_tasks, spawn_seeds

    if not isinstance(plan, NominalPlan):
        raise InvalidInputError(f"plan: expected a NominalPlan, got {type(plan).__name__}")
    if a_prior is None:
        a_prior = getattr(sim, "a_prior", "identity")
    if a_prior not in A_PRIORS:
        raise InvalidInputError(f"a_prior: expected one of {A_PRIORS}, got {a_prior!r}")
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
    if int(n_a_runs) != n_a_runs or n_a_runs < 1:
        raise InvalidInputError(f"n_a_runs: expected a positive integer, got {n_a_runs!r}")
    n_a_runs = int(n_a_runs)
    if int(n_samples) != n_samples or n_samples < 0:
        raise InvalidInputError(f"n_samples: expected a non-negative integer, got {n_samples!r}")
    H0, N0 = observation_model(sim, H, N)

    master = int(seed.integers(2**63)) if isinstance(seed, np.random.Generator) else seed
    step_seeds = spawn_seeds(master, T + 1)
    draws = _param_draws(sim, plan, params_distribution, int(n_samples), step_seeds[T])

    ts = list(range(T))
    n_chunks = 1 if backend == "serial" else max(1, min(T, 4 * (workers or 2)))
    chunks = [ts[k::n_chunks] for k in range(n_chunks)]
    fn = partial(
        _run_chunk, sim, plan, draws, W_factor, eps, a_prior, float(rcond), n_a_runs, step_seeds
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
        a, b, m_, dr, r = per_t[t]
        if a is not None:
            A[t] = a
        B[t], M[t], drift[t], rank[t] = b, m_, dr, r
    if T >= 2:
        A[0], rank[0] = A[1], rank[1]
    else:
        A[0], rank[0] = (np.eye(p) if a_prior == "identity" else np.zeros((p, p))), 0
    deficient = [t for t in range(1, T) if rank[t] < p]
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
            f"(lowest rank {low}; {why}); A_t keeps the '{a_prior}' prior on the unexcited directions",
            RankDeficiencyWarning,
            stacklevel=2,
        )
    m = H0.shape[0]
    scale = getattr(sim, "state_scale", None)
    return Linearization(
        A=A,
        B=B,
        M=M,
        H=np.broadcast_to(H0, (T, m, p)),
        N=np.broadcast_to(N0, (T, m, m)),
        rank=rank,
        drift=drift,
        state_scale=None if scale is None else np.array(scale, dtype=np.float64),
        control_scale=0.5 * (bounds[:, 1] - bounds[:, 0]),
    )


def _run_chunk(sim, plan, draws, W_factor, eps, a_prior, rcond, K, step_seeds, ts):
    return _steps(
        sim, plan, draws, W_factor, eps, a_prior, rcond, K, [step_seeds[t] for t in ts], ts
    )
