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

The paper never says how good the LQG-MP estimate is.
:func:`~riskplan.tissue_planning.calibration_check`
(:mod:`riskplan.tissue_planning.calibration`) puts it next to the success rate of
``n ≥ 1000`` closed-loop executions on the true simulator (each with its own ``s ~ S``,
actuation and sensing noise; :func:`riskplan.control.lqg.monte_carlo_success`) with a 95 %
Wilson interval.
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
    "PlanScore",
    "Selection",
    "common_draws",
    "evaluate_plan",
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
    """Linearise ``plan``, build its LQG controller and its LQG-MP estimate (paper IV-B..D).

    Parameters
    ----------
    sim : Simulator
        The simulator the plan runs on.
    plan : NominalPlan
        The candidate plan.
    distribution : ParamDistribution, list of SimParams or None
        S for ``M_t`` (``None``: ``sim.distribution``).
    method : {"sigma", "truncation", "sampling"}
        The LQG-MP method (:func:`~riskplan.control.lqgmp`).
    n_samples : int
        Draws of S per step.
    n_goal_samples : int
        Draws of the final state for ``P(goal)`` (trajectories with ``"sampling"``).
    n_a_runs : int or None
        A-runs per step of :func:`~riskplan.control.linearize` (``None``: its default
        ``2 min(p, q)``; ``2 * sim.state_dim`` is the paper's).
    Q, R : numpy.ndarray, optional
        LQR costs (default: Bryson's rule from the simulator's scales, see
        :func:`~riskplan.control.lqg.lqg_controller`).
    seed : int, numpy.random.Generator or None
        Seeds the linearisation's perturbations and the goal samples.
    disturbance : bool
        The persistent-disturbance state (beyond the paper,
        :func:`~riskplan.control.lqg_controller`) instead of the paper's LQG.

    Returns
    -------
    controller : LQGController
        The plan's :class:`~riskplan.control.lqg.LQGController`.
    result : LQGMPResult
        Its :class:`~riskplan.control.lqgmp.LQGMPResult`.
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

    Every candidate is evaluated by :func:`evaluate_plan` on the same parameter draws
    (:func:`common_draws`); candidate ``i`` with seed ``spawn_seeds(seed, n)[i]``.

    Parameters
    ----------
    sim : Simulator
        The simulator the plans run on.
    plans : list of NominalPlan
        The candidate :class:`~riskplan.control.NominalPlan` list.
    distribution : ParamDistribution, list of SimParams or None
        S for ``M_t`` (``None``: ``sim.distribution``).
    method : {"sigma", "truncation", "sampling"}
        ``"sigma"`` (the paper's; a conservative bound, far below the model's probability
        for plans passing close to obstacles), ``"truncation"`` (Patil 2012) or
        ``"sampling"`` (trajectories of the linear model), see :mod:`riskplan.control.lqgmp`.
    n_samples, n_goal_samples, n_a_runs, Q, R, disturbance
        As in :func:`evaluate_plan` (``disturbance``: select with the persistent-disturbance
        controller, beyond the paper; default the paper's LQG).
    seed : int or None
        Root of the draws' and the candidates' seeds.
    backend, workers
        As in :func:`riskplan.parallel.map_tasks` (over chunks of candidates).
    on_result : callable, optional
        ``on_result(i, score)``, called as plans finish.

    Returns
    -------
    Selection
        The ranking, the selected plan, its controller and LQG-MP result, every
        candidate's controller. Raises :class:`~riskplan.errors.PlanningError` if no
        candidate could be evaluated.
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
