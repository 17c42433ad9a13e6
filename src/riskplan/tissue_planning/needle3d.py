"""The 3-D needle under uncertainty (beyond the deformable paper's future work), the twin of
:func:`~riskplan.tissue_planning.plan_tissue`: simulator RRT candidates, their controllers
and LQG-MP estimates in 3-D by several methods (:func:`evaluate_candidates`), selection by
the truncation estimate, and optionally the check against closed- and open-loop executions
on common draws (:func:`measure_plan`; the split into tasks and the accuracy checks in
:mod:`~riskplan.tissue_planning.needle3d_checks`), end to end in :func:`plan_needle3d`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

__all__ = [
    "ESTIMATORS",
    "GOAL_SE",
    "MAX_GOAL_SAMPLES",
    "MAX_PARTICLES",
    "PARTICLES_BATCH",
    "PARTICLES_SE",
    "Needle3DResult",
    "PlanRow",
    "evaluate_candidates",
    "measure_plan",
    "plan_needle3d",
]

#: steered edges after a goal-directed one (:class:`~riskplan.tissue_planning.rrt.RRTOptions`
#: ``goal_connect``): enough to cross the block (20 edges of up to 0.3)
GOAL_CONNECT = 20

#: LQG-MP estimators compared on every plan (:func:`riskplan.control.lqgmp3d.lqgmp_3d`): the
#: truncation, per-step, sigma and sampling methods on the second-order model of the true
#: system (:func:`riskplan.control.lqgmp3d_moments.second_order_model`, where the case's only
#: uncertainty is the actuation noise; the linear model otherwise), and ``"linear"``, the
#: truncation on the linear model (the estimate before the model change), and
#: ``"particles"``, Monte Carlo of the reduced closed loop with the exact material step and
#: the controls' clip (:func:`riskplan.control.lqgmp3d_particles.lqgmp_particles`: the
#: final tip's skew, which every Gaussian estimate leaves out; NaN where the second-order
#: model does not apply)
ESTIMATORS = ("truncation", "per-step", "sigma", "sampling", "linear", "particles")

#: standard error of the goal test's draws where they are used — the comparison of
#: :func:`evaluate_candidates` (``PlanRow.draws``) and a target that is not an ellipsoid;
#: the estimates' own goal test is exact (:func:`riskplan.control.lqgmp3d.lqgmp_3d`
#: ``goal="exact"``) — (``goal_se``), set before any run: a tenth of
#: the narrowest 95 % Wilson half-width the check compares against (1000 executions at
#: p = 0.999: 0.0027), so the prediction's own Monte Carlo error cannot move it across an
#: interval's edge by more than a tenth of the interval
GOAL_SE = 3e-4

#: target standard error of the ``"particles"`` estimate, set before any run from the check
#: it serves — within ±2 points (:data:`~riskplan.tissue_planning.needle3d_checks.CHECK_POINTS`)
#: of 10,000 closed-loop executions at ≥ 100× their speed: a fifth of the tolerance, so its
#: own Monte Carlo error moves it across the tolerance's edge by at most a fifth of it (the
#: 10,000 executions' own standard error is at most 0.005). Particles are drawn in batches
#: of :data:`PARTICLES_BATCH` until ``sqrt(p̃(1 − p̃)/n)`` meets it (plans near p = 1 stop
#: after 2000). Against the 95 % Wilson interval of 1000 executions (half-width 0.006 at
#: p = 0.99, 0.018 at p = 0.9) it is a coarser precision than the earlier fixed 30,000
#: particles (a tenth of that half-width)
PARTICLES_SE = 0.004

#: particles per batch of the ``"particles"`` estimate
PARTICLES_BATCH = 2000

#: cap on those particles: 16,000 meet :data:`PARTICLES_SE` at any p
#: (``sqrt(0.25/16,000) = 0.00395``), so the cap only bounds the work
MAX_PARTICLES = 16_000

#: cap on those draws: 10⁶ meet :data:`GOAL_SE` for p ≥ 0.9; below, the Wilson half-width at
#: 1000 executions is ≥ 0.019 and 10⁶ draws (standard error ≤ 5e-4) stay under a tenth of it
MAX_GOAL_SAMPLES = 1_000_000


@dataclass
class PlanRow:
    """One candidate's estimates and measured rates.

    ``estimates``: P(success) by each of :data:`ESTIMATORS`; ``estimate_s``: seconds each
    took; ``closed``: successes of ``n`` closed-loop executions, ``open``: of ``n_open``
    open-loop ones on the first of the same draws, with Wilson intervals; ``outcomes_closed``/``outcomes_open``: counts per outcome;
    ``target_error_closed``/``target_error_open``: mean final distance of the world tip to
    the deformed target centre (Hauser et al.'s targeting error; the plan's own end lies up
    to 0.7 target radii from the centre); ``end_error_closed``/``end_error_open``: mean
    distance of the final tip from the plan's end, both relative to the deformed target
    centre (what feedback corrects; both on the common draws); ``mc_s``: wall seconds of
    the executions (in the stage: of all checked plans' together); ``estimate_cpu_s``: CPU seconds of the linearisation + truncation estimate
    and of the truncation estimate alone (given the controller; ``"truncation_repeats"``:
    two more runs of it, warm); ``closed_cpu_s``: CPU
    seconds of the ``n`` closed-loop executions (the process's own time, so the speed
    ratio does not count other jobs' load); ``estimate_n``/``estimate_se``: each estimate's
    goal-test draws and the standard error of its ``P(success)`` from them
    (:class:`~riskplan.control.lqgmp_common.LQGMPResult` ``n_goal_samples``, ``p_success_se``;
    with the exact goal test, the default, 0 draws and the quadrature's error bound);
    ``draws``: the truncation estimates with the goal test drawn to :data:`GOAL_SE` instead,
    their draws, standard error and CPU seconds (the comparison with the exact test);
    ``structured``: the structured linearisation's check (:func:`~riskplan.tissue_planning.needle3d_checks.measure_structured`);
    ``n_open``: the first draws also executed open loop (the rest closed loop only: ``n``
    counts all), with ``closed_first``/``closed_first_ci``/``closed_first_cpu_s`` the closed
    loop on them (:func:`~riskplan.tissue_planning.needle3d_checks.fill_rates`; the targeting
    errors are on them too); ``checks``: each estimate within
    :data:`~riskplan.tissue_planning.needle3d_checks.CHECK_POINTS` of ``closed/n`` and inside
    ``closed_first_ci`` (:func:`~riskplan.tissue_planning.needle3d_checks.accuracy_checks`);
    ``speed``: the executions' CPU over each prediction's
    (:func:`~riskplan.tissue_planning.needle3d_checks.speed_ratios`)."""

    index: int
    n_steps: int
    estimates: dict
    estimate_s: dict
    n: int = 0
    closed: int = 0
    closed_ci: tuple = (0.0, 0.0)
    open: int = 0
    open_ci: tuple = (0.0, 0.0)
    outcomes_closed: dict = field(default_factory=dict)
    outcomes_open: dict = field(default_factory=dict)
    target_error_closed: float = float("nan")
    target_error_open: float = float("nan")
    end_error_closed: float = float("nan")
    end_error_open: float = float("nan")
    mc_s: float = 0.0
    estimate_cpu_s: dict = field(default_factory=dict)
    closed_cpu_s: float = 0.0
    estimate_n: dict = field(default_factory=dict)
    estimate_se: dict = field(default_factory=dict)
    draws: dict = field(default_factory=dict)
    structured: dict = field(default_factory=dict)
    n_open: int = 0
    closed_first: int = 0
    closed_first_ci: tuple = (0.0, 0.0)
    closed_first_cpu_s: float = 0.0
    checks: dict = field(default_factory=dict)
    speed: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        """The row as a plain dictionary (what ``summary.json`` holds per row).

        Returns
        -------
        dict
            Field name -> value (a shallow copy of the row's fields).
        """
        return dict(self.__dict__)


def evaluate_candidates(
    sim,
    plans,
    *,
    seed=0,
    n_samples: int = 16,
    n_goal_samples: int = 4000,
    goal_se: float | None = GOAL_SE,
):
    """Every candidate's controller and its LQG-MP estimates by each of :data:`ESTIMATORS`.

    The controller is linearised along the candidate with ``sim.distribution``
    (:func:`~riskplan.tissue_planning.evaluate_plan`, truncation). The goal test is exact
    (the comparison in ``PlanRow.draws`` draws it, in batches of ``n_goal_samples`` to a
    standard error of ``goal_se``, at most :data:`MAX_GOAL_SAMPLES`); ``"sampling"`` uses
    ``n_goal_samples`` trajectories, ``"particles"`` runs to :data:`PARTICLES_SE` (batches of
    :data:`PARTICLES_BATCH`, at most :data:`MAX_PARTICLES`). CPU seconds in
    ``estimate_cpu_s``: ``"truncation"`` the prediction given the controller (the
    second-order model and the truncation on it), ``"truncation+linearise"`` with the
    linearisation and the controller's gains, ``"linear"`` the linear model's truncation,
    ``"truncation_repeats"`` two more runs of the prediction (a list); ``"per-step"``,
    ``"sigma"``, ``"sampling"`` and ``"particles"`` the second-order model and the method.

    Parameters
    ----------
    sim : riskplan.scenarios.Needle3DScenario
        The 3-D needle scenario, with its ``distribution`` (the case's uncertainty).
    plans : sequence of riskplan.control.NominalPlan
        The candidates, in the frame ``sim`` reads.
    seed : int or numpy.random.SeedSequence, optional
        Master seed; candidate ``i`` gets the ``i``-th of
        :func:`~riskplan.parallel.spawn_seeds` ``(seed, len(plans))``.
    n_samples : int, optional
        Perturbed simulator runs per step of the statistical linearisation.
    n_goal_samples : int, optional
        Goal-test draws per batch, and the ``"sampling"`` method's trajectories.
    goal_se : float or None, optional
        Target standard error of the drawn goal test (``None``: one batch).

    Returns
    -------
    controllers : list
        Per candidate its LQG controller, ``None`` where the linearisation failed.
    rows : list of PlanRow
        Per candidate (in order) its estimates, seconds, CPU seconds, goal-test draws and
        standard errors; a candidate whose linearisation fails gets estimates of 0.
    """
    from riskplan.parallel import spawn_seeds
    from riskplan.tissue_planning.needle3d_checks import actuation_cov

    W = actuation_cov(sim)
    ctrls, rows = [], []
    kw = dict(n_goal_samples=n_goal_samples)
    kw_se = dict(kw, goal_se=goal_se, max_goal_samples=MAX_GOAL_SAMPLES)
    for i, (plan, s) in enumerate(zip(plans, spawn_seeds(seed, len(plans)))):
        ctrl, row = _evaluate_one(sim, plan, i, s, W, n_samples, kw, kw_se)
        ctrls.append(ctrl)
        rows.append(row)
    return ctrls, rows


def _evaluate_one(sim, plan, i, s, W, n_samples, kw, kw_se):
    """Candidate ``i`` of :func:`evaluate_candidates` (seed ``s``, ``W`` the actuation
    covariance or ``None``): ``(controller or None, PlanRow)``."""
    from riskplan.control import linearize
    from riskplan.control.lqg import lqg_controller
    from riskplan.control.lqgmp3d import lqgmp_3d
    from riskplan.control.lqgmp3d_moments import second_order_model
    from riskplan.control.lqgmp3d_particles import lqgmp_particles
    from riskplan.parallel import spawn_seeds
    from riskplan.tissue_planning.needle3d_checks import drawn_estimate, repeat_cpu
    from riskplan.tissue_planning.select import _FAILURES

    c0 = time.process_time()
    try:
        # evaluate_plan's linearisation and gains (its seed split), without its estimate
        lin = linearize(sim, plan, n_samples=n_samples, seed=spawn_seeds(s, 2)[0])
        ctrl = lqg_controller(lin)
        c_lin = time.process_time() - c0
        c0 = time.process_time()
        got = {"linear": lqgmp_3d(sim, plan, ctrl, method="truncation", seed=s, **kw_se)}
    except _FAILURES as exc:
        log.warning("needle3d: candidate %d not linearised (%s)", i, exc)
        return None, PlanRow(i, plan.n_steps, dict.fromkeys(ESTIMATORS, 0.0), {})
    cpu = {"linear": time.process_time() - c0}
    c0 = time.process_time()
    mo = None if W is None else second_order_model(sim, plan, ctrl, W)
    c_model = time.process_time() - c0
    c0 = time.process_time()
    got["truncation"] = lqgmp_3d(sim, plan, ctrl, method="truncation", seed=s, moments=mo, **kw_se)
    cpu["truncation"] = c_model + time.process_time() - c0
    drawn = drawn_estimate(sim, plan, ctrl, s, mo, c_model, kw_se)
    cpu["truncation_repeats"] = repeat_cpu(sim, plan, ctrl, s, W, kw_se)
    # the linearisation and gains (evaluate_plan less its linear estimate) + the prediction
    cpu["truncation+linearise"] = c_lin + cpu["truncation"]
    secs = {"truncation": cpu["truncation"]}
    for m in ESTIMATORS[1:4]:
        t0, c0 = time.perf_counter(), time.process_time()
        mkw = kw if m == "sampling" else kw_se
        got[m] = lqgmp_3d(sim, plan, ctrl, method=m, seed=s, moments=mo, **mkw)
        secs[m] = time.perf_counter() - t0
        cpu[m] = c_model + time.process_time() - c0
    if mo is not None and getattr(sim, "position_is_measured", False):
        c0 = time.process_time()
        got["particles"] = lqgmp_particles(
            sim,
            plan,
            ctrl,
            mo,
            W,
            n_particles=MAX_PARTICLES,
            seed=s,
            p_se=PARTICLES_SE,
            batch=PARTICLES_BATCH,
            keep_moments=False,
        )
        cpu["particles"] = c_model + time.process_time() - c0
    nan = float("nan")
    return ctrl, PlanRow(
        i,
        plan.n_steps,
        {m: got[m].p_success if m in got else nan for m in ESTIMATORS},
        secs,
        estimate_cpu_s=cpu,
        estimate_n={m: got[m].n_goal_samples if m in got else 0 for m in ESTIMATORS},
        estimate_se={m: got[m].p_success_se if m in got else nan for m in ESTIMATORS},
        draws=drawn,
    )


def measure_plan(
    sim, plan, controller, row: PlanRow, *, n: int, seed=0, n_open: int | None = None
) -> PlanRow:
    """Closed-loop executions of ``plan`` on ``n`` draws and open-loop ones on the first
    ``n_open`` of them (common draws), in one process.

    Each draw takes the parameters and actuation from ``sim.distribution`` and the closed
    loop's sensing noise from the same generator
    (:func:`~riskplan.tissue_planning.needle3d_checks.execute_draws`); the counts, Wilson
    intervals, outcomes and targeting errors (final distance of the world tip to the
    deformed target centre) go into ``row``
    (:func:`~riskplan.tissue_planning.needle3d_checks.fill_rates`).

    Parameters
    ----------
    sim : riskplan.scenarios.Needle3DScenario
        The scenario, in the frame ``controller`` reads.
    plan : riskplan.control.NominalPlan
        The plan executed.
    controller : riskplan.control.LQGController
        Its LQG controller (from :func:`evaluate_candidates`).
    row : PlanRow
        The plan's row, filled in place.
    n : int
        Closed-loop executions.
    seed : int or numpy.random.SeedSequence, optional
        Master seed of the draws (:func:`~riskplan.parallel.spawn_seeds` ``(seed, n)``).
    n_open : int or None, optional
        Open-loop executions on the first of the same draws (``None``: all ``n``).

    Returns
    -------
    PlanRow
        ``row``, its rates, outcomes, targeting errors, CPU and wall seconds (``mc_s``) set.
    """
    from riskplan.parallel import spawn_seeds
    from riskplan.tissue_planning.needle3d_checks import execute_draws, fill_rates

    t0 = time.perf_counter()
    n_open = n if n_open is None else min(int(n_open), n)
    part = execute_draws((sim, plan, controller, spawn_seeds(seed, n), n_open))
    fill_rates(row, [part], n_open)
    row.mc_s = time.perf_counter() - t0
    return row


@dataclass
class Needle3DResult:
    """What :func:`plan_needle3d` returns: the candidates (world frame), the rows (ranked by
    the truncation estimate), the selected index, its controller, timings (``rrt_s``,
    ``selection_s``, ``executions_s``) and the settings."""

    plans: list
    rows: list
    best: int
    controller: object
    timings: dict
    settings: dict


def _candidates(sim, n_plans, seed, max_iterations, workers) -> list:
    """The simulator RRT's candidates for :func:`plan_needle3d` (world frame)."""
    from riskplan.tissue_planning.rrt import RRTOptions, rrt_plans

    plans, _ = rrt_plans(
        sim,
        n_plans,
        seed=seed,
        # goal bias 0.5 and a target tightened to 0.7 of its radius: with the defaults (0.3,
        # 0.5) trees of 600 iterations found 0-1 plans; with these, 3-5 in 400 (seeds 10, 11).
        # goal_connect: a goal-directed edge is followed by steered edges until blocked
        # (RRT-Connect); the trees of seeds 1-3 found 13 plans in 10.2 s of CPU with it,
        # 10 plans in 11.7 s without (docs/scenarios.md)
        options=RRTOptions(
            plans_per_tree=5,
            max_iterations=max_iterations,
            goal_bias=0.5,
            goal_depth=0.3,
            goal_connect=GOAL_CONNECT,
        ),
        workers=workers,
        backend="local" if (workers or 0) != 1 else "serial",
    )
    return plans


def plan_needle3d(
    case: str = "actuation",
    *,
    n_plans: int = 10,
    seed: int = 0,
    check_runs: int = 0,
    open_runs: int | None = None,
    structured: bool = False,
    check_plans: int = 6,
    max_iterations: int = 600,
    workers: int | None = None,
    config=None,
    frame: str = "world",
) -> Needle3DResult:
    """Plan the 3-D needle: simulator RRT candidates, LQG-MP (truncation) selection and,
    optionally, the check against executions.

    With ``check_runs > 0``: ``check_runs`` closed-loop executions of the selected plan and
    of ``check_plans − 1`` more spread over the ranking, open-loop ones on the first
    ``open_runs`` of the same draws, split into tasks of
    :data:`~riskplan.tissue_planning.needle3d_checks.DRAWS_PER_TASK` draws over the workers
    (:func:`~riskplan.tissue_planning.needle3d_checks.measure_checked`); each checked row
    gets its accuracy checks and speed ratios (:class:`PlanRow` ``checks``, ``speed``).

    Parameters
    ----------
    case : str, optional
        The uncertainty case (:data:`riskplan.scenarios.CASE_NAMES`).
    n_plans : int, optional
        Candidate plans.
    seed : int, optional
        Master seed: the trees and the linearisations from ``seed``, the executions' draws
        from ``seed + 1`` (the same draws for each checked plan).
    check_runs : int, optional
        Closed-loop executions per checked plan (0: no check).
    open_runs : int or None, optional
        Open-loop executions on the first of the same draws, and the Wilson check on them
        (``None``: all ``check_runs``).
    structured : bool, optional
        Also check the structured linearisation's controller on the first ``open_runs``
        draws (:func:`~riskplan.tissue_planning.needle3d_checks.measure_structured`).
    check_plans : int, optional
        Plans checked (the selected one and others spread over the ranking).
    max_iterations : int, optional
        RRT iterations per tree.
    workers : int or None, optional
        Worker processes (:func:`~riskplan.parallel.map_tasks`; 1: in this process).
    config : optional
        A scenario configuration or file for ``needle3d`` (``None``: the default block).
    frame : str, optional
        The reduced state the linearisation, the controllers and LQG-MP read
        (:data:`riskplan.scenarios.FRAMES`; the RRT plans in the world frame, its plans are
        reframed).

    Returns
    -------
    Needle3DResult
        The candidates (in the world frame), the ranked rows, the selected index, its
        controller, timings and settings.

    Raises
    ------
    riskplan.errors.InvalidInputError
        On an unknown ``case`` or ``frame``, a negative ``check_runs``, or a
        ``check_plans`` or ``open_runs`` below 1.
    """
    from riskplan._validation import check_choice, check_count
    from riskplan.scenarios import CASE_NAMES, FRAMES
    from riskplan.scenarios.registry import scenario_from_config

    # checked before any work (an unknown frame would otherwise fail after the RRT)
    check_choice(case, CASE_NAMES, "case")
    check_choice(frame, FRAMES, "frame")
    check_count(check_runs, "check_runs", 0, integral=True)
    check_count(check_plans, "check_plans", 1, integral=True)
    if open_runs is not None:
        check_count(open_runs, "open_runs", 1, integral=True)
    sim = scenario_from_config("needle3d", config, case)
    t0 = time.perf_counter()
    plans = _candidates(sim, n_plans, seed, max_iterations, workers)
    t_rrt = time.perf_counter() - t0
    t0 = time.perf_counter()
    world_plans = plans
    if frame != "world":
        sim = sim.with_frame(frame)
        plans = [p.reframed(sim) for p in plans]
    ctrls, rows = evaluate_candidates(sim, plans, seed=seed)
    t_sel = time.perf_counter() - t0
    ranked = sorted(rows, key=lambda r: (-r.estimates["truncation"], r.index))
    best = ranked[0].index
    t0 = time.perf_counter()
    open_runs = check_runs if open_runs is None else min(int(open_runs), check_runs)
    if check_runs:
        ranked = _check_ranked(
            sim, plans, ctrls, ranked, check_runs, open_runs, check_plans, seed, structured, workers
        )
    t_mc = time.perf_counter() - t0
    return Needle3DResult(
        plans=world_plans,
        rows=ranked,
        best=best,
        controller=ctrls[best],
        timings={"rrt_s": t_rrt, "selection_s": t_sel, "executions_s": t_mc},
        settings=dict(
            case=case,
            n_plans=n_plans,
            seed=seed,
            check_runs=check_runs,
            open_runs=open_runs,
            n_elements=sim.nominal_params.n_elements,
            frame=frame,
        ),
    )


def _check_ranked(sim, plans, ctrls, ranked, n, n_open, check_plans, seed, structured, workers):
    """The check of :func:`plan_needle3d`: ``check_plans`` rows evenly spaced over the
    ranking (the selected one first) executed; returns the ranking with them filled."""
    from riskplan.tissue_planning.calibration import evenly_spaced_ranks
    from riskplan.tissue_planning.needle3d_checks import measure_checked

    # the candidates are distinct plans (rrt_plans keeps a path repeated by several trees once)
    usable = [r for r in ranked if ctrls[r.index] is not None]
    chosen = [usable[k] for k in evenly_spaced_ranks(len(usable), min(check_plans, len(usable)))]
    done = measure_checked(
        sim,
        plans,
        ctrls,
        chosen,
        n=n,
        n_open=n_open,
        # the same draws for each plan; seed + 1, not a spawn_seeds child: the common draws
        # docs/results.md quotes as "seed 1" (the first 1000 draws reproduced) are this stream
        seed=seed + 1,
        structured=structured,
        workers=workers,
    )
    by_index = {r.index: r for r in done}
    return [by_index.get(r.index, r) for r in ranked]
