"""LQG-MP plan selection (Patil, van den Berg & Alterovitz, RSS 2011, section IV-D) and the
check of its estimate against closed-loop executions (beyond the paper).

For every candidate plan π (from :func:`riskplan.tissue_planning.rrt.rrt_plans`):

1. linearise the simulator along π (paper IV-B, :func:`riskplan.control.linearize`), with
   the uncertainty case's parameter distribution S for the process noise ``M_t``;
2. LQR and Kalman gains (paper IV-C, :func:`riskplan.control.lqg.lqg_controller`);
3. the LQG-MP probability of success ``P(success) = P(no collision) · P(goal)`` of the
   a-priori distributions of the controlled plan (paper IV-D, :func:`riskplan.control.lqgmp`);

and select the plan with the highest ``P(success)``. Plans are independent, so they run in
parallel through :mod:`riskplan.parallel`; plan ``i`` uses seed ``spawn_seeds(seed, n)[i]``
for its linearisation and goal samples, so the ranking does not depend on the backend.
Every plan's ``M_t`` uses the same ``n_samples`` draws ``s_i ~ S`` (common random numbers:
the plans are compared under the same parameter draws, and the FEM models of those draws
are built once per worker instead of once per plan).
A plan whose linearisation fails (a solver that does not converge along it, a non-finite
state) gets ``P(success) = 0`` and its error message; it is never selected.

The paper never says how good the LQG-MP estimate is. :func:`honesty_check` puts it next
to the success rate of ``n ≥ 1000`` closed-loop executions on the true simulator (each
with its own ``s ~ S``, actuation and sensing noise;
:func:`riskplan.control.lqg.monte_carlo_success`) with a 95 % Wilson interval.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from riskplan._validation import check_count
from riskplan.errors import (
    ConvergenceError,
    ElementInversionError,
    InvalidInputError,
    NumericalError,
    SimulationError,
)

log = logging.getLogger(__name__)

__all__ = [
    "SATURATED",
    "Calibration",
    "HonestyRow",
    "PlanScore",
    "Selection",
    "calibration_metrics",
    "common_draws",
    "evaluate_plan",
    "evenly_spaced_ranks",
    "honesty_check",
    "select_plan",
    "tie_note",
]

_FAILURES = (
    ConvergenceError,
    ElementInversionError,
    NumericalError,
    SimulationError,
    np.linalg.LinAlgError,
)


@dataclass(frozen=True)
class PlanScore:
    """LQG-MP estimate of candidate ``index``: ``p_success``, ``p_collision_free``,
    ``p_goal``, its number of steps, ``error`` (the message if evaluation failed) and the
    CPU seconds its evaluation took."""

    index: int
    p_success: float
    p_collision_free: float
    p_goal: float
    n_steps: int
    error: str | None = None
    cpu_s: float = 0.0


@dataclass
class Selection:
    """Result of :func:`select_plan`.

    ``ranking``: the scores sorted by ``p_success`` (highest first, ties by index);
    ``best``: index of the selected plan in the candidate list; ``plan``: that plan;
    ``controller``: its :class:`~riskplan.control.lqg.LQGController` (``L (T, q, p)``,
    ``K (T, p, m)``, ``P (T, p, p)`` and the linearisation ``A, B, M, H, N``);
    ``result``: its :class:`~riskplan.control.lqgmp.LQGMPResult`; ``controllers``: the
    controller of every candidate (``None`` where evaluation failed), for later checks;
    ``n_tied``: how many evaluated candidates share the best ``p_success`` (1: the
    selection is decided; more: a tie LQG-MP cannot break, resolved by the lowest index,
    which :attr:`tie_note` says in words).
    """

    ranking: list
    best: int
    plan: object
    controller: object
    result: object
    controllers: list = field(default_factory=list)
    method: str = "sigma"
    n_tied: int = 1

    @property
    def tie_note(self) -> str | None:
        """``None`` when one candidate is best; otherwise a sentence saying the selection
        is a tie (e.g. all candidates at ``P(success) = 1.000``)."""
        return tie_note(self.n_tied, len(self.ranking), self.score(self.best).p_success)

    def score(self, index: int) -> PlanScore:
        """The score of candidate ``index``.

        Parameters
        ----------
        index : int
            The candidate's index among the plans evaluated.

        Returns
        -------
        PlanScore
            Its score.

        Raises
        ------
        InvalidInputError
            When no candidate has that index.
        """
        for s in self.ranking:
            if s.index == index:
                return s
        raise InvalidInputError(f"index: no candidate {index}")


def evaluate_plan(
    sim,
    plan,
    distribution=None,
    *,
    method: str = "sigma",
    n_samples: int = 16,
    n_goal_samples: int = 2000,
    n_a_runs: int | None = None,
    Q=None,
    R=None,
    seed=None,
    disturbance: bool = False,
):
    """Linearise ``plan``, build its LQG controller and its LQG-MP estimate.

    Returns ``(controller, result)`` (:class:`~riskplan.control.lqg.LQGController`,
    :class:`~riskplan.control.lqgmp.LQGMPResult`). ``distribution``: S for ``M_t`` (``None``:
    ``sim.distribution``); ``n_samples``: its draws per step; ``n_a_runs``: the A-runs per
    step of :func:`~riskplan.control.linearize` (``None``: its default ``2 min(p, q)``;
    ``2 * sim.state_dim`` is the paper's); ``Q``, ``R``: LQR costs (default: Bryson's rule from the simulator's scales, see
    :func:`~riskplan.control.lqg.lqg_controller`);
    ``seed``: linearisation perturbations and goal samples; ``disturbance``: the
    persistent-disturbance state (beyond the paper, :func:`~riskplan.control.lqg_controller`)
    instead of the paper's LQG.
    """
    from riskplan.control import linearize
    from riskplan.control.lqg import lqg_controller
    from riskplan.control.lqgmp import lqgmp
    from riskplan.parallel import spawn_seeds

    s_lin, s_mp = spawn_seeds(seed, 2)
    lin = linearize(
        sim,
        plan,
        distribution,
        n_samples=n_samples,
        n_a_runs=n_a_runs,
        seed=s_lin,
        disturbance=disturbance,
    )
    controller = lqg_controller(lin, Q=Q, R=R, disturbance=disturbance)
    result = lqgmp(sim, plan, controller, method=method, n_goal_samples=n_goal_samples, seed=s_mp)
    return controller, result


def _evaluate_one(index, sim, plan, draws, kwargs, seed):
    import time

    cpu0 = time.process_time()
    try:
        controller, result = evaluate_plan(sim, plan, draws, seed=seed, **kwargs)
    except _FAILURES as exc:
        score = PlanScore(
            index, 0.0, 0.0, 0.0, plan.n_steps, error=str(exc), cpu_s=time.process_time() - cpu0
        )
        return score, None, None
    score = PlanScore(
        index,
        float(result.p_success),
        float(result.p_collision_free),
        float(result.p_goal),
        plan.n_steps,
        cpu_s=time.process_time() - cpu0,
    )
    return score, controller, result


def _evaluate_chunk(args):
    import warnings

    sim, items, draws, kwargs = args
    with warnings.catch_warnings():
        # rank-deficient X_t is expected along straight stretches; the linearisation
        # documents its treatment, and a hundred repeated warnings help nobody
        warnings.simplefilter("ignore", RuntimeWarning)
        return [_evaluate_one(i, sim, plan, draws, kwargs, seed) for i, plan, seed in items]


def select_plan(
    sim,
    plans,
    distribution=None,
    *,
    method: str = "sigma",
    n_samples: int = 16,
    n_goal_samples: int = 2000,
    n_a_runs: int | None = None,
    Q=None,
    R=None,
    seed=0,
    backend: str = "local",
    workers: int | None = None,
    on_result=None,
    disturbance: bool = False,
) -> Selection:
    """Evaluate every candidate with LQG-MP and select the most likely to succeed (paper IV-D).

    ``plans``: the candidate :class:`~riskplan.control.NominalPlan` list; ``method``:
    ``"sigma"`` (the paper's; a conservative bound, far below the model's probability for
    plans passing close to obstacles), ``"truncation"`` (Patil 2012) or ``"sampling"``
    (trajectories of the linear model), see :mod:`riskplan.control.lqgmp`; ``n_a_runs``:
    A-runs per step of the linearisation (:func:`evaluate_plan`); ``disturbance``: select
    with the persistent-disturbance controller (beyond the paper; default the paper's LQG);
    ``on_result(i, score)`` is called as plans finish.
    Raises :class:`~riskplan.errors.PlanningError` if no candidate could be evaluated.
    """
    from riskplan.errors import PlanningError
    from riskplan.parallel import chunk_count, map_tasks, spawn_seeds

    plans = list(plans)
    if not plans:
        raise InvalidInputError("plans: expected at least one candidate plan")
    draws = common_draws(sim, distribution, n_samples, seed)
    kwargs = dict(
        method=method,
        n_samples=n_samples,
        n_goal_samples=n_goal_samples,
        n_a_runs=n_a_runs,
        Q=Q,
        R=R,
        disturbance=disturbance,
    )
    seeds = spawn_seeds(seed, len(plans))
    items = list(zip(range(len(plans)), plans, seeds))
    # one simulator per chunk: a scenario travels without its FEM caches, so chunks of plans
    # (interleaved for balance) share the mesh and the models of the common draws
    n_chunks = chunk_count(len(plans), backend, workers)
    chunks = [items[k::n_chunks] for k in range(n_chunks)]
    out = [None] * len(plans)

    def collect(k, res):
        for i, r in zip(range(k, len(plans), n_chunks), res):
            out[i] = r
            if on_result is not None:
                on_result(i, r[0])

    map_tasks(
        _evaluate_chunk,
        [(sim, c, draws, kwargs) for c in chunks],
        backend=backend,
        workers=workers,
        chunksize=1,
        on_result=collect,
    )
    scores = [o[0] for o in out]
    ranking = sorted(scores, key=lambda s: (-s.p_success, s.index))
    ok = [s for s in ranking if s.error is None]
    if not ok:
        raise PlanningError(
            f"plan selection: none of the {len(plans)} candidates could be linearised ({scores[0].error})"
        )
    best = ok[0].index
    n_tied = sum(1 for s in ok if s.p_success == ok[0].p_success)
    if n_tied > 1:
        log.info(tie_note(n_tied, len(plans), ok[0].p_success))
    return Selection(
        ranking=ranking,
        best=best,
        plan=plans[best],
        controller=out[best][1],
        result=out[best][2],
        controllers=[o[1] for o in out],
        method=method,
        n_tied=n_tied,
    )


def tie_note(n_tied: int, n_candidates: int, p_best: float) -> str | None:
    """The sentence that reports a tie for the best LQG-MP score (``None`` if ``n_tied``
    is 1): the selection cannot tell those candidates apart, and takes the first.

    Parameters
    ----------
    n_tied : int
        Number of candidates sharing the best score.
    n_candidates : int
        Number of candidates.
    p_best : float
        The best LQG-MP ``P(success)``.

    Returns
    -------
    str or None
        The sentence, or ``None`` without a tie.
    """
    if n_tied <= 1:
        return None
    who = "all" if n_tied == n_candidates else f"{n_tied} of"
    return (
        f"tie: {who} {n_candidates} candidates share the best LQG-MP P(success) = "
        f"{p_best:.3f}; the selection cannot break it and takes the first of them"
    )


def common_draws(sim, distribution, n_samples: int, seed) -> list | None:
    """The ``n_samples`` parameter draws ``s_i ~ S`` every candidate's ``M_t`` uses.

    Parameters
    ----------
    sim : Simulator
        The simulator (its ``distribution`` is used when ``distribution`` is ``None``).
    distribution : ParamDistribution, list of SimParams or None
        The distribution ``S`` to draw from, or the draws themselves (returned as a list).
    n_samples : int
        Number of draws (non-negative).
    seed : int, numpy.random.Generator or None
        Seeds the draws (a stream apart from the per-plan seeds).

    Returns
    -------
    list of SimParams or None
        The draws, or ``None`` without a distribution.
    """
    from riskplan.parallel import spawn_seeds

    distribution = getattr(sim, "distribution", None) if distribution is None else distribution
    if distribution is None:
        return None
    if isinstance(distribution, (list, tuple)):
        return list(distribution)
    n_samples = check_count(n_samples, "n_samples", 0, integral=True)
    s = spawn_seeds(seed, 1)[0] ^ 0x5EED  # apart from the per-plan seeds
    return list(distribution.sample_many(int(n_samples), s))


@dataclass(frozen=True)
class HonestyRow:
    """One candidate in the check: its LQG-MP ``p_lqgmp`` and the Monte Carlo success rate
    ``p_mc`` of ``n`` closed-loop executions with its 95 % interval ``[low, high]``, and
    whether the estimate lies inside that interval.

    ``index`` is the candidate's 0-based position in the candidate list (as in
    ``candidates.npz``); ``rank`` its 1-based place in the LQG-MP ranking (1 = the selected
    plan), the same count in tables and files."""

    index: int
    rank: int
    p_lqgmp: float
    p_mc: float
    low: float
    high: float
    n: int

    @property
    def inside(self) -> bool:
        return self.low <= self.p_lqgmp <= self.high


def honesty_check(
    sim,
    plans,
    selection: Selection,
    distribution=None,
    *,
    others: int = 2,
    n: int = 1000,
    seed=0,
    backend: str = "local",
    workers: int | None = None,
    on_row=None,
) -> list[HonestyRow]:
    """LQG-MP ``P(success)`` against the success rate of ``n`` closed-loop LQG executions
    for the selected plan and ``others`` more (at even quantiles of the ranking, down to the
    worst usable candidate).

    Each execution draws ``s ~ distribution`` (``None``: ``sim.distribution``) and its
    sensing noise (:func:`riskplan.control.lqg.monte_carlo_success`). ``on_row(row)`` is
    called as each candidate's check finishes.
    """
    from riskplan.control.lqg import monte_carlo_success
    from riskplan.parallel import spawn_seeds

    n = check_count(n, "n", 1, integral=True)
    others = check_count(others, "others", 0, integral=True)
    distribution = getattr(sim, "distribution", None) if distribution is None else distribution
    usable = [s for s in selection.ranking if s.error is None]
    # the selected plan, then ``others`` ranks at even quantiles of the rest (the last one the worst)
    k = min(int(others), len(usable) - 1)
    picks = [0] + sorted(
        set(np.linspace(0, len(usable) - 1, k + 1)[1:].round().astype(int).tolist())
    )
    seeds = spawn_seeds(seed, len(picks))
    rows = []
    for rank, s in zip(picks, seeds):
        score = usable[rank]
        est = monte_carlo_success(
            sim,
            plans[score.index],
            selection.controllers[score.index],
            distribution,
            n=int(n),
            seed=s,
            backend=backend,
            workers=workers,
        )
        rows.append(
            HonestyRow(
                index=score.index,
                rank=rank + 1,
                p_lqgmp=score.p_success,
                p_mc=est.probability,
                low=est.low,
                high=est.high,
                n=est.n,
            )
        )
        if on_row is not None:
            on_row(rows[-1])
    return rows


# ---- calibration of a predicted P(success) against measured rates (beyond the paper) -----

#: A set of measured rates all at or above this says nothing about calibration: every
#: estimator that predicts "near 1" scores well on it (issue: a saturated set).
SATURATED = 0.98


@dataclass(frozen=True)
class Calibration:
    """How well predicted probabilities match measured rates over ``n_plans`` (plan, case)
    pairs (:func:`calibration_metrics`).

    ``mae``: mean absolute error ``(1/n) Σ |p̂_i − r_i|``; ``spearman``: Spearman's rank
    correlation of ``p̂`` and ``r`` (``None`` where undefined: fewer than 3 pairs or a
    constant side); ``measured_spread``: ``max r − min r``; ``measured_min``,
    ``measured_max``; ``informative``: the set can judge calibration — the rank correlation
    is defined and not every measured rate is ``≥`` :data:`SATURATED`; ``meets_goal``:
    informative, ``mae ≤ mae_goal`` and ``spearman ≥ spearman_goal``.
    """

    mae: float
    spearman: float | None
    n_plans: int
    measured_spread: float
    measured_min: float
    measured_max: float
    informative: bool
    meets_goal: bool

    def as_dict(self) -> dict:
        """The fields as a JSON-serialisable dict.

        Returns
        -------
        dict
            The fields by name.
        """
        from dataclasses import asdict

        return asdict(self)


def calibration_metrics(
    predicted, measured, *, mae_goal: float = 0.05, spearman_goal: float = 0.8
) -> Calibration:
    """Calibration of predicted probabilities ``predicted (n,)`` against measured success
    rates ``measured (n,)`` (both in [0, 1]): mean absolute error, Spearman's rank
    correlation (:func:`scipy.stats.spearmanr`, ties by average rank) and the spread of the
    measured rates. Raises :class:`~riskplan.errors.InvalidInputError` for mismatched
    shapes, an empty set, or values outside [0, 1].
    """
    import warnings

    from scipy.stats import spearmanr

    p = np.asarray(predicted, dtype=np.float64)
    r = np.asarray(measured, dtype=np.float64)
    if p.ndim != 1 or r.shape != p.shape or p.size == 0:
        raise InvalidInputError(
            f"predicted, measured: expected two equal non-empty 1-D arrays, got shapes {p.shape} and {r.shape}"
        )
    for name, v in (("predicted", p), ("measured", r)):
        if not np.all(np.isfinite(v)) or v.min() < 0.0 or v.max() > 1.0:
            raise InvalidInputError(f"{name}: expected probabilities in [0, 1]")
    mae = float(np.abs(p - r).mean())
    rho = None
    if p.size >= 3 and np.ptp(p) > 0 and np.ptp(r) > 0:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # ConstantInputWarning is excluded above
            rho = float(spearmanr(p, r).statistic)
        if not np.isfinite(rho):
            rho = None
    informative = rho is not None and bool(r.min() < SATURATED)
    return Calibration(
        mae=mae,
        spearman=rho,
        n_plans=int(p.size),
        measured_spread=float(r.max() - r.min()),
        measured_min=float(r.min()),
        measured_max=float(r.max()),
        informative=informative,
        meets_goal=bool(informative and mae <= mae_goal and rho >= spearman_goal),
    )


def evenly_spaced_ranks(n: int, k: int) -> list[int]:
    """``min(k, n)`` distinct ranks ``0 … n − 1`` evenly spaced over the ranking (the first
    and the last included): ``round(linspace(0, n − 1, k))``; all ranks when ``k ≥ n``.

    Parameters
    ----------
    n : int
        Number of ranks (positive).
    k : int
        Number of ranks wanted (positive).

    Returns
    -------
    list of int
        The ranks, ascending.
    """
    n, k = check_count(n, "n", 1, integral=True), check_count(k, "k", 1, integral=True)
    if k >= n:
        return list(range(int(n)))
    return sorted(set(np.linspace(0, n - 1, int(k)).round().astype(int).tolist()))
