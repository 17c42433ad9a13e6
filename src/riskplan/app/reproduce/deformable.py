"""The evaluation of the deformable-planning paper (Patil, van den Berg & Alterovitz, RSS 2011,
section V, Fig. 6): the paper's four methods (and one more reading of a baseline) × five
uncertainty cases × ``n`` simulated executions, for
the needle (§V-A) and the manipulation (§V-B) scenario.

Methods (the paper's §V-A comparison; choices it leaves open are stated here). The
baselines use the **plain simulator RRT** the paper describes (§IV-A: the tree ends a plan
at its first state in the goal region, controls from the whole bounds): our RRT's
robustness margins (``goal_depth``: goal nodes within half the goal radius;
``control_margin``: controls 2σ of the actuation noise inside the bounds; see
:class:`riskplan.tissue_planning.rrt.RRTOptions`) are switched off for them and kept for ours.
The kinodynamic RRT's goal steering and goal-entry ranking (search, not margins) stay on
for all.

1. ``rrt`` — **RRT with deformations**: a plain simulator-RRT plan made in the deforming
   tissue with the expected parameters (:func:`riskplan.tissue_planning.rrt.rrt_plans`),
   executed open loop (``u_t = u*_t``). The plan is candidate 0, the first the RRT
   returns (the paper says "a RRT plan").
   ``rrt_margins`` — the same baseline on candidate 0 of *our* RRT (with margins), open
   loop: the other reading of the baseline, shown beside it.
2. ``lqgmp_only`` — **LQG-MP only**: plain-RRT candidates planned in a *static* tissue,
   i.e. with the interaction force switched off (``force_scale = 0``, which the paper
   itself calls "no deformations" in case 5). Each is linearised on that static model
   (A, B) with the process noise M estimated from draws ``s ~ S`` of the case *with*
   deformation (so deformation enters as noise), and the candidate with the highest
   LQG-MP probability of success is executed with its LQG controller. Not applicable to
   the manipulation scenario: there the deformation *is* the motion (without force the
   target never moves, so a static model has no plan to the goal); the paper defines this
   baseline for the needle only (§V-A). Reported as ``None`` with the reason.
3. ``ours_no_select`` — **ours without the LQG-MP step**: candidate 0 of our deforming
   candidates (the plan of ``rrt_margins``) with its LQG controller; the only difference
   to ``rrt_margins`` is feedback, the only difference to method 4 is the selection.
4. ``ours`` — the candidate of highest LQG-MP ``P(success)``
   (:func:`riskplan.control.lqgmp.lqgmp`) with its LQG controller.

A candidate whose linearisation fails (the simulator's solve along it) gets LQG-MP
``P(success) = 0`` and is never selected; if it is candidate 0, method 3 has no controller
and executes it open loop, which ``controller_error`` in the results records.

Selection is done per uncertainty case: the linearisation's process noise ``M_t``
(paper §IV-B) is estimated from that case's S, so LQG-MP sees the uncertainty the plan
will meet. Each execution ``i`` of a case draws ``s_i ~ S`` and its sensing noise from
seed ``i`` of the case (:func:`riskplan.parallel.spawn_seeds`); the four methods share
these seeds (common random numbers: a difference between methods is not draw luck).

Success: no collision at any state and the final state in the (deformed) goal
(:func:`riskplan.control.lqg.execute`). Every failed execution is counted under its
outcome: collision, missed goal, left the tissue (the needle's material point outside the
body), or solver failure of the true simulator (with its reason), never silently as a
collision or a success. Intervals: 95 % Wilson
(:func:`riskplan.collision.binomial_interval`).

Work units and resumability: plans, per-(candidate, case) controllers and LQG-MP values,
and batches of executions are stored as they finish (:class:`BlobStore` for pickled
objects, :class:`~riskplan.app.store.ResultStore` for JSON numbers), so a rerun
continues where the last one stopped and gives the same numbers.

Modules: the methods, cases and sizes in :mod:`~riskplan.app.reproduce.deformable_setup`,
the pool tasks in :mod:`~riskplan.app.reproduce.deformable_tasks`, the numbers and the
paper's claims in :mod:`~riskplan.app.reproduce.deformable_numbers`, the open-vs-closed
runs in :mod:`~riskplan.app.reproduce.feedback`, seeds and blobs in
:mod:`~riskplan.app.reproduce.work_units`; this module runs the steps in order
(:func:`run_scenario`) and one scenario with its timings (:func:`run_one_scenario`). Their
names are importable from here too.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from riskplan.app.reproduce.deformable_numbers import (
    case_numbers,
    claims,
    highest_verdict,
    mechanism,
    selection_values,
)
from riskplan.app.reproduce.deformable_setup import (
    EVAL_CASES,
    METHOD_LABELS,
    METHODS,
    NOT_APPLICABLE,
    OPEN_LOOP,
    SCALES,
    SELECTED_SETS,
    ScenarioScale,
)
from riskplan.app.reproduce.deformable_tasks import (
    _outcome_counts as _outcome_counts,
)
from riskplan.app.reproduce.deformable_tasks import (
    evaluate_candidate,
    execute_batch,
    execute_methods,
)
from riskplan.app.reproduce.feedback import (
    SINGLE_RUNS,
    _feedback_rates,
    open_closed_rates,
    paired_outcomes,
    single_executions,
)
from riskplan.app.reproduce.work_units import BlobStore, _seed_for, stage_map
from riskplan.errors import InvalidInputError

log = logging.getLogger(__name__)

__all__ = [
    "EVAL_CASES",
    "METHODS",
    "METHOD_LABELS",
    "SCALES",
    "SINGLE_RUNS",
    "BlobStore",
    "ScenarioScale",
    "claims",
    "evaluate_candidate",
    "execute_batch",
    "execute_methods",
    "highest_verdict",
    "open_closed_rates",
    "paired_outcomes",
    "run_one_scenario",
    "run_scenario",
    "single_executions",
]


@dataclass(frozen=True)
class _Run:
    """What the steps of one scenario's run share: the scenario, its sizes, the stores, the
    root seed, the task map and progress callback, the RRT's backend and workers, and the
    key prefix of the selections, executions and open-vs-closed runs (``fig6.<name>``, or
    ``fig6d.<name>`` for the disturbance controller)."""

    name: str
    scale: ScenarioScale
    store: object
    blobs: BlobStore
    seed: int
    pmap: object
    report: object
    backend: str
    workers: int | None
    pre: str


def run_scenario(
    name: str,
    scale: ScenarioScale,
    store,
    *,
    seed: int = 0,
    backend: str = "local",
    workers: int | None = None,
    ray_address: str | None = None,
    progress=None,
    cases=EVAL_CASES,
    pool=None,
    make_sim=None,
    disturbance: bool = False,
) -> dict:
    """The Fig. 6 evaluation of scenario ``name`` (``"needle"`` or ``"manipulation"``).

    Parameters
    ----------
    name : ``"needle"`` or ``"manipulation"``.
    scale : sizes (:class:`ScenarioScale`).
    store : :class:`~riskplan.app.store.ResultStore`; finished work is read from and
        written to it (resumable).
    seed : master seed; every part derives its own (:func:`_seed_for`).
    backend, workers, ray_address : :func:`riskplan.parallel.imap_tasks`.
    progress : optional ``progress(stage, done, total)`` callback.
    cases : the uncertainty cases to evaluate, each handed to ``make_sim`` (default
        ``EVAL_CASES``: the paper's five).
    pool : a :class:`riskplan.parallel.TaskPool` to run the selection and execution tasks on
        (the RRT candidates use the enclosing ``with TaskPool`` block's pool); ``None``: as
        :func:`riskplan.parallel.imap_tasks` decides.
    make_sim : ``make_sim(name, case) -> simulator`` with its distribution S (default
        :func:`riskplan.scenarios.registry.make_scenario`); for variants of the cases
        (sensitivity studies, :mod:`riskplan.app.reproduce.needle_study`).
    disturbance : the closed-loop methods use the persistent-disturbance controller and
        its LQG-MP (:func:`riskplan.control.lqg_controller` with ``disturbance=True``;
        beyond the paper) instead of the paper's LQG. The candidates are the same; the
        selections, executions and open-vs-closed runs are stored under ``fig6d.<name>``,
        so both variants can share one store (and its RRT candidates).

    Returns
    -------
    JSON-serialisable dict: ``mechanism[case]``: :func:`paired_outcomes` of
    ``rrt_margins`` (open loop) against ``ours_no_select`` (the same plan closed loop) on the
    same draws; ``cases[case][method]`` with ``successes``, ``n``, ``rate``,
    ``low``, ``high`` (95 % Wilson), the outcomes ``collided``, ``missed_goal``,
    ``solver_failed`` (with ``solver_failure_reasons``: reason -> count), ``left_tissue``
    (:data:`riskplan.control.lqg.OUTCOMES`; they add up to ``n`` with the successes),
    ``predicted`` (LQG-MP ``P(success)`` of the executed plan, ``None`` open loop),
    ``candidate``, and for the selecting methods ``n_tied`` (candidates sharing the best
    LQG-MP value) with ``tie`` (the sentence saying so, ``None`` when decided); ``selection[case][set]`` the LQG-MP values of every candidate.
    """
    from riskplan.scenarios.registry import make_scenario

    _check_run(name, backend, cases)
    run = _Run(
        name=name,
        scale=scale,
        store=store,
        blobs=BlobStore(store),
        seed=seed,
        pmap=stage_map(backend, workers, ray_address, pool),
        report=progress or (lambda stage, done, total: None),
        backend=backend,
        workers=workers,
        pre=f"fig6d.{name}" if disturbance else f"fig6.{name}",
    )
    na = NOT_APPLICABLE.get(name, {})
    make = make_sim or make_scenario
    plans = _candidate_plans(run, make(name, "nominal"), na)
    sims = {c: make(name, c) for c in cases}
    selected_sets = [s for s in plans if s in SELECTED_SETS]
    selection = _selection(run, sims, plans, selected_sets, cases, disturbance)
    chosen, ties = _choose(cases, na, plans, selection)
    flags, n_batches = _executions(run, sims, plans, chosen, cases)
    # 4b. Fig. 7(c-f) as rates: the ``ours`` plan open vs closed loop on common draws
    feedback = _feedback_rates(
        name, scale, store, chosen, plans, sims, seed, run.pmap, run.report, run.pre
    )
    # 5. numbers
    out_cases = case_numbers(cases, na, flags, n_batches, chosen, ties, plans)
    return {
        "scenario": name,
        "scale": asdict(scale),
        "disturbance": bool(disturbance),
        "not_applicable": dict(na),
        "candidates": {s: len(p) for s, p in plans.items()},
        "plan_steps": {s: [int(p.n_steps) for p in ps] for s, ps in plans.items()},
        "cases": out_cases,
        "selection": selection_values(cases, selected_sets, selection, plans),
        "feedback": feedback,
        "claims": claims(out_cases),
        # the mechanism: the same plan open and closed loop on the same draws
        "mechanism": mechanism(cases, flags, n_batches, chosen),
    }


def _check_run(name: str, backend: str, cases) -> None:
    """The scenario, backend and case names of :func:`run_scenario`, checked once."""
    from riskplan.parallel import BACKENDS
    from riskplan.scenarios.registry import SCENARIO_NAMES

    if name not in SCENARIO_NAMES:
        raise InvalidInputError(f"scenario: expected one of {SCENARIO_NAMES}, got {name!r}")
    if backend not in BACKENDS:
        raise InvalidInputError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    for c in cases:
        if c not in EVAL_CASES:
            raise InvalidInputError(f"cases: expected names from {EVAL_CASES}, got {c!r}")


def _candidate_plans(run: _Run, base, na: dict) -> dict[str, list]:
    """Step 1, ``{set: plans}``: the candidates in the deforming tissue with our RRT's
    margins (ours), the plain RRT in the deforming tissue (RRT with deformations) and,
    where ``lqgmp_only`` applies (needle), the plain RRT in a static tissue (LQG-MP only)."""
    from riskplan.tissue_planning.rrt import rrt_plans

    scale, name = run.scale, run.name
    plain = dataclasses.replace(scale.rrt_options(), goal_depth=0.0, control_margin=0.0)
    sets = {"deforming": (base.nominal_params, scale.rrt_options())}
    sets["plain"] = (base.nominal_params, plain)
    if "lqgmp_only" not in na:
        sets["static"] = (base.nominal_params.replace(force_scale=0.0), plain)
    plans: dict[str, list] = {}
    for k, (set_name, (params, options)) in enumerate(sets.items()):
        key = f"fig6.{name}.plans.{set_name}"
        run.report(f"{name}: RRT candidates ({set_name})", k, len(sets))

        def compute(params=params, set_name=set_name, options=options):
            ps, _ = rrt_plans(
                base,
                scale.n_candidates,
                seed=_seed_for(run.seed, name, "rrt", set_name),
                params=params,
                options=options,
                backend=run.backend,
                workers=run.workers,
            )
            return ps

        plans[set_name] = run.blobs.get_or_compute(key, compute)
        run.report(f"{name}: RRT candidates ({set_name})", k + 1, len(sets))
    return plans


def _selection(run: _Run, sims: dict, plans: dict, selected_sets, cases, disturbance) -> dict:
    """Step 2, ``{(case, set, candidate): evaluate_candidate result}``: every candidate of
    the ranked sets linearised under each case's S, with its LQG gains and LQG-MP values
    (a worker's cases share B_t's runs); stored one by one."""
    name, scale = run.name, run.scale
    sel_items = [(c, s, j) for s in selected_sets for j in range(len(plans[s])) for c in cases]
    sel_key = {it: f"{run.pre}.select.{it[0]}.{it[1]}.{it[2]:03d}" for it in sel_items}
    selection: dict = {it: run.blobs.get(sel_key[it]) for it in sel_items}
    todo = [it for it in sel_items if selection[it] is None]
    done = len(sel_items) - len(todo)
    run.report(f"{name}: linearise + LQG-MP", done, len(sel_items))
    tasks = [
        (
            sims[c],
            plans[s][j],
            scale.lin_samples,
            scale.goal_samples,
            _seed_for(run.seed, name, "select", c, s, j),
            *((True,) if disturbance else ()),
        )
        for (c, s, j) in todo
    ]
    for i, res in run.pmap(evaluate_candidate, tasks):
        selection[todo[i]] = res
        run.blobs.put(sel_key[todo[i]], res)
        done += 1
        run.report(f"{name}: linearise + LQG-MP", done, len(sel_items))
    return selection


def _choose(cases, na: dict, plans: dict, selection: dict) -> tuple[dict, dict]:
    """Step 3, which plan and controller each method executes: ``chosen[case, method] =
    (set, candidate, selection result or None)`` and, for the selecting methods,
    ``ties[case, method]`` (how many candidates share the best LQG-MP value)."""
    chosen: dict = {}
    ties: dict = {}
    for c in cases:
        for m in METHODS:
            if m in na:
                continue
            if m == "rrt":
                chosen[c, m] = ("plain", 0, None)
            elif m == "rrt_margins":
                chosen[c, m] = ("deforming", 0, None)
            elif m == "ours_no_select":
                chosen[c, m] = ("deforming", 0, selection[c, "deforming", 0])
            else:
                s = "static" if m == "lqgmp_only" else "deforming"
                ps = [selection[c, s, j]["p_success"] for j in range(len(plans[s]))]
                j = int(np.argmax(ps))  # first of the best on ties (reported: "tie")
                chosen[c, m] = (s, j, selection[c, s, j])
                ties[c, m] = int(np.sum(np.asarray(ps) == ps[j]))
    return chosen, ties


def _executions(run: _Run, sims: dict, plans: dict, chosen: dict, cases) -> tuple[dict, int]:
    """Step 4, ``(flags, n_batches)``: the executions of every chosen (case, method) in
    stored batches, ``flags[case, method, batch]`` the rows of :func:`execute_batch`.
    Execution ``i`` of a case uses seed ``i`` of the case for every method."""
    from riskplan.parallel import spawn_seeds

    name = run.name
    n, bs = run.scale.n_executions, run.scale.batch_size
    n_batches = -(-n // bs)
    case_seeds = {c: spawn_seeds(_seed_for(run.seed, name, "execute", c), n) for c in cases}
    batch_items = [(c, m, b) for (c, m) in chosen for b in range(n_batches)]
    bkey = {it: f"{run.pre}.exec.{it[0]}.{it[1]}.b{it[2]:05d}" for it in batch_items}
    flags: dict = {it: run.store.get(bkey[it]) for it in batch_items}
    todo = [it for it in batch_items if flags[it] is None]
    done = len(batch_items) - len(todo)
    run.report(f"{name}: executions", done * bs, len(batch_items) * bs)

    # one task per (case, batch) runs every method still missing there on the same draws
    # (execute_methods: a draw's FEM model and mesh are built once for all methods)
    groups: dict = {}
    for c, m, b in todo:
        groups.setdefault((c, b), []).append(m)

    def run_of(c, m):
        s, j, sel = chosen[c, m]
        # None also if its linearisation failed
        return (plans[s][j], None if m in OPEN_LOOP else sel["controller"])

    group_items = list(groups.items())
    tasks = [
        (sims[c], [run_of(c, m) for m in ms], case_seeds[c][b * bs : (b + 1) * bs])
        for (c, b), ms in group_items
    ]
    for i, res in run.pmap(execute_methods, tasks):
        (c, b), ms = group_items[i]
        for m, rows in zip(ms, res):
            flags[c, m, b] = rows
            run.store.put(bkey[c, m, b], rows)
            done += 1
            run.report(f"{name}: executions", done * bs, len(batch_items) * bs)
    return flags, n_batches


def run_one_scenario(
    scenario: str,
    out,
    *,
    scale_name: str = "smoke",
    disturbance: bool = False,
    candidates: int | None = None,
    executions: int | None = None,
    workers: int | None = None,
    seed: int = 0,
    progress=None,
) -> dict:
    """Fig. 6 of one scenario into ``out`` (``riskplan study fig6``; resumable: ``out/store``).

    Parameters
    ----------
    scenario : {"needle", "manipulation"}
        The scenario.
    out : path-like
        Output folder; ``fig6_<scenario>[_disturbance].json`` holds the :func:`run_scenario`
        result and ``timings_<...>.json`` the wall seconds per stage and the CPU seconds of
        this process (``cpu_s_self``) and of its worker processes (``cpu_s_workers``).
    scale_name : {"smoke", "paper"}
        The scale whose counts are used.
    disturbance : bool
        Use the persistent-disturbance controller and its LQG-MP (beyond the paper).
    candidates, executions : int, optional
        Replace the scale's candidate and execution counts (a reduced run; the result
        records the sizes that ran).
    workers : int, optional
        Local worker processes (``None``: one per core).
    seed : int
        Root seed.
    progress : callable, optional
        ``progress(stage, done, total)``.

    Returns
    -------
    dict
        The :func:`run_scenario` result.
    """
    from riskplan.app.store import ResultStore
    from riskplan.io import write_json_atomic
    from riskplan.parallel import TaskPool

    scale = _sized_scale(scenario, scale_name, candidates, executions)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    store = ResultStore(
        out / "store",
        {"figure": "fig6", "scenario": scenario, "sizes": asdict(scale), "seed": seed},
    )
    clock = _StageClock(progress)
    with TaskPool("local", workers) as pool:
        res = run_scenario(
            scenario,
            scale,
            store,
            seed=seed,
            backend="local",
            workers=workers,
            pool=pool,
            progress=clock,
            disturbance=disturbance,
        )
    tag = scenario + ("_disturbance" if disturbance else "")
    write_json_atomic(out / f"fig6_{tag}.json", res)
    write_json_atomic(out / f"timings_{tag}.json", clock.record(pool.workers_cpu_s))
    return res


def _sized_scale(scenario: str, scale_name: str, candidates, executions) -> ScenarioScale:
    """The named scale of ``scenario`` with the candidate and execution counts replaced
    where given (the open-vs-closed runs capped at the executions)."""
    if scenario not in ("needle", "manipulation"):
        raise InvalidInputError(f"scenario: expected needle or manipulation, got {scenario!r}")
    if scale_name not in SCALES:
        raise InvalidInputError(f"scale: expected one of {sorted(SCALES)}, got {scale_name!r}")
    scale = SCALES[scale_name][scenario]
    if candidates is not None:
        scale = dataclasses.replace(scale, n_candidates=candidates)
    if executions is not None:
        scale = dataclasses.replace(
            scale, n_executions=executions, n_feedback=min(scale.n_feedback, executions)
        )
    return scale


class _StageClock:
    """A ``progress(stage, done, total)`` callback that records each stage's first and last
    report in wall seconds since its creation (``start_s``, ``end_s``, ``done``, ``total``)
    and passes the call on to ``progress``; :meth:`record` adds the wall seconds so far and
    the CPU seconds of this process and of the pool's workers."""

    def __init__(self, progress=None):
        self.t0 = time.perf_counter()
        self.stages: dict = {}
        self.progress = progress

    def __call__(self, stage, done, total):
        now = time.perf_counter() - self.t0
        st = self.stages.setdefault(stage, {"start_s": now, "end_s": now, "total": total})
        st["end_s"] = now
        st["done"] = done
        if self.progress is not None:
            self.progress(stage, done, total)

    def record(self, workers_cpu_s: float | None) -> dict:
        """The timings: ``workers_cpu_s`` is the pool's (``TaskPool.workers_cpu_s``: its
        workers are the forkserver's children, which ``RUSAGE_CHILDREN`` never counts);
        ``None`` stays ``None`` (not measurable here)."""
        import resource

        own = resource.getrusage(resource.RUSAGE_SELF)
        return {
            "wall_s": time.perf_counter() - self.t0,
            "cpu_s_self": own.ru_utime + own.ru_stime,
            "cpu_s_workers": workers_cpu_s,
            "stages": self.stages,
        }
