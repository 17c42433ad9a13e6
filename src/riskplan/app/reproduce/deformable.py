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
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import pickle
import warnings
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path

import numpy as np

from riskplan._validation import check_count
from riskplan.errors import DataFormatError, InvalidInputError

log = logging.getLogger(__name__)

__all__ = [
    "EVAL_CASES",
    "METHODS",
    "METHOD_LABELS",
    "SCALES",
    "BlobStore",
    "ScenarioScale",
    "claims",
    "evaluate_candidate",
    "execute_batch",
    "execute_methods",
    "highest_verdict",
    "open_closed_rates",
    "paired_outcomes",
    "run_scenario",
    "single_executions",
]

METHODS = ("rrt", "rrt_margins", "lqgmp_only", "ours_no_select", "ours")
METHOD_LABELS = {
    "rrt": "RRT with deformations (plain RRT, open loop)",
    "rrt_margins": "RRT with deformations, our RRT's margins (open loop)",
    "lqgmp_only": "LQG-MP only (static plans)",
    "ours_no_select": "ours without LQG-MP selection",
    "ours": "ours",
}
#: Methods executed without feedback.
OPEN_LOOP = ("rrt", "rrt_margins")
#: Candidate sets that are linearised and ranked by LQG-MP.
SELECTED_SETS = ("deforming", "static")

#: The paper's five uncertainty cases (riskplan.scenarios.uncertainty.CASE_NAMES minus nominal).
EVAL_CASES = ("material-low", "material-high", "actuation", "mesh", "force")

NOT_APPLICABLE = {
    "manipulation": {
        "lqgmp_only": "no static plan exists: without force the target never moves (paper §V-A defines this baseline for the needle)"
    }
}


@dataclass(frozen=True)
class ScenarioScale:
    """Sizes of one scenario's evaluation.

    ``n_candidates``: RRT candidates per set (paper: 100); ``n_executions`` per method and
    case (paper: 1000); ``batch_size``: executions per stored work unit; ``lin_samples``:
    parameter draws for ``M_t``; ``goal_samples``: LQG-MP draws for ``P(goal)``;
    ``plans_per_tree`` / ``max_iterations`` / ``n_controls``: the RRT budget
    (:class:`riskplan.tissue_planning.rrt.RRTOptions`); ``n_feedback``: executions of each
    open-vs-closed condition of :mod:`riskplan.app.reproduce.feedback` (Figs. 4, 5 and
    7(c-f) as rates; 0: not run).
    """

    n_candidates: int
    n_executions: int
    batch_size: int
    lin_samples: int = 16
    goal_samples: int = 2000
    plans_per_tree: int = 5
    max_iterations: int = 4000
    n_controls: int = 6
    n_feedback: int = 0

    def __post_init__(self):
        for name in (
            "n_candidates",
            "n_executions",
            "batch_size",
            "plans_per_tree",
            "max_iterations",
            "n_controls",
            "goal_samples",
        ):
            check_count(getattr(self, name), name, 1)
        check_count(self.n_feedback, "n_feedback", 0)
        check_count(self.lin_samples, "lin_samples", 2)

    def rrt_options(self):
        from riskplan.tissue_planning.rrt import RRTOptions

        return RRTOptions(
            n_controls=self.n_controls,
            max_iterations=self.max_iterations,
            plans_per_tree=self.plans_per_tree,
        )


#: Named scales. ``smoke`` fits ``riskplan reproduce --paper all`` in about 5 minutes on two
#: cores; ``paper`` is the paper's (100 candidates, 1000 executions per method and case).
SCALES: dict[str, dict[str, ScenarioScale]] = {
    "smoke": {
        "needle": ScenarioScale(
            n_candidates=2,
            n_executions=20,
            batch_size=10,
            lin_samples=6,
            goal_samples=300,
            plans_per_tree=2,
            n_feedback=10,
        ),
        "manipulation": ScenarioScale(
            n_candidates=2,
            n_executions=6,
            batch_size=3,
            lin_samples=4,
            goal_samples=300,
            plans_per_tree=2,
            n_feedback=10,
        ),
    },
    "paper": {
        "needle": ScenarioScale(
            n_candidates=100, n_executions=1000, batch_size=50, plans_per_tree=10, n_feedback=200
        ),
        "manipulation": ScenarioScale(
            n_candidates=100,
            n_executions=1000,
            batch_size=20,
            plans_per_tree=10,
            n_feedback=200,
        ),
    },
}


class BlobStore:
    """Pickled work products (plans, controllers) beside a ResultStore, hash-checked.

    ``DIR/blobs/<key>.pkl`` holds the bytes; the ResultStore record ``blob.<key>`` holds their
    SHA-256, written after the file, so a blob without a record is simply recomputed and a
    blob whose bytes do not match its record raises :class:`DataFormatError` naming the file.
    Only files this store wrote are ever unpickled (the hash is checked first).
    """

    def __init__(self, store):
        self.store = store
        self.dir = Path(store.root) / "blobs"
        self.dir.mkdir(parents=True, exist_ok=True)

    def get(self, key: str):
        rec = self.store.get(f"blob.{key}")
        if rec is None:
            return None
        path = self.dir / f"{key}.pkl"
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise DataFormatError(f"{path}: results blob missing or unreadable ({exc})") from exc
        if hashlib.sha256(data).hexdigest() != rec["sha256"]:
            raise DataFormatError(f"{path}: corrupted results blob (content hash mismatch)")
        return pickle.loads(data)

    def put(self, key: str, obj) -> None:
        from riskplan.io import atomic_path

        data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        path = self.dir / f"{key}.pkl"
        with atomic_path(path) as tmp:
            Path(tmp).write_bytes(data)
        self.store.put(
            f"blob.{key}", {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
        )

    def get_or_compute(self, key: str, compute):
        found = self.get(key)
        if found is not None:
            return found
        obj = compute()
        self.put(key, obj)
        return obj


# ---- tasks (module level: picklable for process pools and Ray) ---------------------------


def evaluate_candidate(args):
    """``args = (sim, plan, lin_samples, goal_samples, seed)``: linearise one candidate under one case's S, LQG gains, LQG-MP (paper §IV-B..D), with
    :func:`riskplan.tissue_planning.select.evaluate_plan`. A candidate whose linearisation fails
    (the simulator's solve along it) gets ``P(success) = 0``, no controller, and its error.
    An optional sixth element ``disturbance`` (default ``False``) selects the
    persistent-disturbance controller and its LQG-MP (beyond the paper)."""
    from riskplan.errors import (
        ConvergenceError,
        ElementInversionError,
        NumericalError,
        SimulationError,
    )
    from riskplan.tissue_planning.select import evaluate_plan

    # NumericalError: LQG-MP's propagation or a point covariance of a degenerate linear model
    failures = (
        ConvergenceError,
        ElementInversionError,
        NumericalError,
        SimulationError,
        np.linalg.LinAlgError,
    )

    sim, plan, lin_samples, goal_samples, seed, *rest = args
    disturbance = bool(rest[0]) if rest else False
    with warnings.catch_warnings():
        # rank-deficient X_t along straight stretches is expected and documented by linearize
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            ctrl, res = evaluate_plan(
                sim,
                plan,
                sim.distribution,
                n_samples=lin_samples,
                n_goal_samples=goal_samples,
                seed=seed,
                disturbance=disturbance,
            )
        except failures as exc:
            return {
                "p_success": 0.0,
                "p_collision_free": 0.0,
                "p_goal": 0.0,
                "controller": None,
                "error": str(exc),
            }
    return {
        "p_success": float(res.p_success),
        "p_collision_free": float(res.p_collision_free),
        "p_goal": float(res.p_goal),
        "controller": ctrl,
        "error": None,
    }


def execute_batch(args) -> list[list]:
    """``args = (sim, plan, controller or None, seeds)``: one batch of executions:
    ``[[success, collided, reached_goal, solver_failed, left_tissue, reason], ...]`` (flags
    0/1; ``reason`` the solver's message for a solver failure, else ``None``;
    :func:`riskplan.control.lqg.execute`): :func:`execute_methods` with one run."""
    sim, plan, controller, seeds = args
    return execute_methods((sim, [(plan, controller)], seeds))[0]


def execute_methods(args) -> list[list[list]]:
    """``args = (sim, runs, seeds)`` with ``runs = [(plan, controller or None), ...]``: the
    executions of several methods on the same draws, draw by draw: for each seed the
    parameters ``s ~ S`` are drawn once and every run executes under them, so the FEM model
    (and, in the mesh case, the mesh) of a draw is built once for all methods instead of
    once per method. Returns one list per run, each as :func:`execute_batch` returns it
    for ``(sim, plan, controller, seeds)``, bit for bit (each execution is a function of
    its seed only)."""
    from riskplan.control.lqg import execute

    sim, runs, seeds = args
    out: list[list] = [[] for _ in runs]
    for s in seeds:
        for k, (plan, controller) in enumerate(runs):
            # a fresh generator per run: the sensing noise of each starts where the draw of
            # s leaves it, so that a run's executions do not depend on the other runs
            gen = np.random.default_rng(s)
            params = sim.distribution.sample(gen)
            ex = execute(sim, plan, controller, params, seed=gen, keep_states=False)
            out[k].append(
                [
                    int(ex.success),
                    int(ex.collided),
                    int(ex.reached_goal),
                    int(ex.outcome == "solver_failure"),
                    int(ex.left_tissue),
                    ex.error if ex.outcome == "solver_failure" else None,
                ]
            )
    return out


def _outcome_counts(rows: list) -> tuple[np.ndarray, dict]:
    """Flags ``(n, 5)`` int and the solver-failure reasons with their counts, from the rows
    of :func:`execute_batch`."""
    f = np.array([r[:5] for r in rows], dtype=np.int64).reshape(-1, 5)
    reasons: dict = {}
    for r in rows:
        if r[3] and r[5] is not None:
            # the step index varies; the reason is what follows it
            key = str(r[5]).split(": ", 1)[-1]
            reasons[key] = reasons.get(key, 0) + 1
    return f, reasons


def _seed_for(seed: int, *labels) -> int:
    """A 63-bit seed for a named part of the run (stable across runs and backends)."""
    words = [int(seed)] + [
        int.from_bytes(hashlib.sha256(str(x).encode()).digest()[:4], "little") for x in labels
    ]
    return int(np.random.SeedSequence(words).generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def _wilson(k: int, n: int) -> tuple[float, float]:
    from riskplan.collision import binomial_interval

    lo, hi = binomial_interval(k, n, confidence=0.95)
    return float(lo), float(hi)


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
    scale : sizes (:class:`ScenarioScale`).
    store : :class:`~riskplan.app.store.ResultStore`; finished work is read from and
        written to it (resumable).
    seed : master seed; every part derives its own (:func:`_seed_for`).
    backend, workers, ray_address : :func:`riskplan.parallel.imap_tasks`.
    progress : optional ``progress(stage, done, total)`` callback.
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
    from riskplan.parallel import BACKENDS, imap_tasks, spawn_seeds
    from riskplan.scenarios.registry import SCENARIO_NAMES, make_scenario
    from riskplan.tissue_planning.rrt import rrt_plans
    from riskplan.tissue_planning.select import tie_note

    if name not in SCENARIO_NAMES:
        raise InvalidInputError(f"scenario: expected one of {SCENARIO_NAMES}, got {name!r}")
    if backend not in BACKENDS:
        raise InvalidInputError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    for c in cases:
        if c not in EVAL_CASES:
            raise InvalidInputError(f"cases: expected names from {EVAL_CASES}, got {c!r}")
    blobs = BlobStore(store)
    report = progress or (lambda stage, done, total: None)
    pmap = partial(
        imap_tasks,
        backend=backend,
        workers=workers,
        ray_address=ray_address,
        chunksize=1,
        pool=pool,
    )
    na = NOT_APPLICABLE.get(name, {})

    # 1. candidate plans: deforming tissue with our RRT's margins (ours), the plain RRT in
    # the deforming tissue (RRT with deformations) and (needle) in a static tissue (LQG-MP only)
    make = make_sim or make_scenario
    base = make(name, "nominal")
    plain = dataclasses.replace(scale.rrt_options(), goal_depth=0.0, control_margin=0.0)
    sets = {"deforming": (base.nominal_params, scale.rrt_options())}
    sets["plain"] = (base.nominal_params, plain)
    if "lqgmp_only" not in na:
        sets["static"] = (base.nominal_params.replace(force_scale=0.0), plain)
    plans: dict[str, list] = {}
    for k, (set_name, (params, options)) in enumerate(sets.items()):
        key = f"fig6.{name}.plans.{set_name}"
        report(f"{name}: RRT candidates ({set_name})", k, len(sets))

        def compute(params=params, set_name=set_name, options=options):
            ps, _ = rrt_plans(
                base,
                scale.n_candidates,
                seed=_seed_for(seed, name, "rrt", set_name),
                params=params,
                options=options,
                backend=backend,
                workers=workers,
            )
            return ps

        plans[set_name] = blobs.get_or_compute(key, compute)
        report(f"{name}: RRT candidates ({set_name})", k + 1, len(sets))

    # 2. per candidate, case by case (a worker's cases share B_t's runs): linearise, LQG, LQG-MP
    sims = {c: make(name, c) for c in cases}
    selected_sets = [s for s in plans if s in SELECTED_SETS]
    sel_items = [(c, s, j) for s in selected_sets for j in range(len(plans[s])) for c in cases]
    pre = f"fig6d.{name}" if disturbance else f"fig6.{name}"
    sel_key = {it: f"{pre}.select.{it[0]}.{it[1]}.{it[2]:03d}" for it in sel_items}
    selection: dict = {it: blobs.get(sel_key[it]) for it in sel_items}
    todo = [it for it in sel_items if selection[it] is None]
    done = len(sel_items) - len(todo)
    report(f"{name}: linearise + LQG-MP", done, len(sel_items))
    tasks = [
        (
            sims[c],
            plans[s][j],
            scale.lin_samples,
            scale.goal_samples,
            _seed_for(seed, name, "select", c, s, j),
            *((True,) if disturbance else ()),
        )
        for (c, s, j) in todo
    ]
    for i, res in pmap(evaluate_candidate, tasks):
        selection[todo[i]] = res
        blobs.put(sel_key[todo[i]], res)
        done += 1
        report(f"{name}: linearise + LQG-MP", done, len(sel_items))

    # 3. which plan and controller each method executes
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

    # 4. executions in batches
    n, bs = scale.n_executions, scale.batch_size
    n_batches = -(-n // bs)
    case_seeds = {c: spawn_seeds(_seed_for(seed, name, "execute", c), n) for c in cases}
    batch_items = [(c, m, b) for (c, m) in chosen for b in range(n_batches)]
    bkey = {it: f"{pre}.exec.{it[0]}.{it[1]}.b{it[2]:05d}" for it in batch_items}
    flags: dict = {it: store.get(bkey[it]) for it in batch_items}
    todo = [it for it in batch_items if flags[it] is None]
    done = len(batch_items) - len(todo)
    report(f"{name}: executions", done * bs, len(batch_items) * bs)

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
    for i, res in pmap(execute_methods, tasks):
        (c, b), ms = group_items[i]
        for m, rows in zip(ms, res):
            flags[c, m, b] = rows
            store.put(bkey[c, m, b], rows)
            done += 1
            report(f"{name}: executions", done * bs, len(batch_items) * bs)

    # 4b. Fig. 7(c-f) as rates: the ``ours`` plan open vs closed loop on common draws
    feedback = _feedback_rates(name, scale, store, chosen, plans, sims, seed, pmap, report, pre)

    # 5. numbers
    out_cases: dict = {}
    for c in cases:
        out_cases[c] = {}
        for m in METHODS:
            if m in na:
                out_cases[c][m] = None
                continue
            f, reasons = _outcome_counts([row for b in range(n_batches) for row in flags[c, m, b]])
            k = int(f[:, 0].sum())
            lo, hi = _wilson(k, len(f))
            s, j, sel = chosen[c, m]
            out_cases[c][m] = {
                "successes": k,
                "n": len(f),
                "rate": k / len(f),
                "low": lo,
                "high": hi,
                "collided": int(f[:, 1].sum()),
                "missed_goal": int(
                    ((f[:, 0] == 0) & (f[:, 1] == 0) & (f[:, 3] == 0) & (f[:, 4] == 0)).sum()
                ),
                "solver_failed": int(f[:, 3].sum()),
                "left_tissue": int(f[:, 4].sum()),
                "solver_failure_reasons": reasons,
                "predicted": None if m in OPEN_LOOP else sel["p_success"],
                "controller_error": None if m in OPEN_LOOP else sel.get("error"),
                "candidate_set": s,
                "candidate": j,
                "n_tied": ties.get((c, m)),
                "tie": None
                if (c, m) not in ties
                else tie_note(ties[c, m], len(plans[s]), sel["p_success"]),
            }
    # the mechanism: the same plan open and closed loop on the same draws
    mechanism = {}
    for c in cases:
        if (c, "rrt_margins") not in chosen or (c, "ours_no_select") not in chosen:
            continue
        rows = {
            m: _outcome_counts([row for b in range(n_batches) for row in flags[c, m, b]])[0]
            for m in ("rrt_margins", "ours_no_select")
        }
        mechanism[c] = paired_outcomes(rows["rrt_margins"][:, 0], rows["ours_no_select"][:, 0])
    sel_out = {
        c: {
            s: [
                {k: v for k, v in selection[c, s, j].items() if k != "controller"}
                for j in range(len(plans[s]))
            ]
            for s in selected_sets
        }
        for c in cases
    }
    return {
        "scenario": name,
        "scale": asdict(scale),
        "disturbance": bool(disturbance),
        "not_applicable": dict(na),
        "candidates": {s: len(p) for s, p in plans.items()},
        "plan_steps": {s: [int(p.n_steps) for p in ps] for s, ps in plans.items()},
        "cases": out_cases,
        "selection": sel_out,
        "feedback": feedback,
        "claims": claims(out_cases),
        "mechanism": mechanism,
    }


def paired_outcomes(open_ok, closed_ok) -> dict:
    """Open against closed loop on the same draws (``(n,)`` success flags each): how many
    runs ``both`` succeed, ``neither``, ``only_open``, ``only_closed`` (feedback rescued
    them), and the rates. Feedback that changes nothing leaves ``only_*`` at 0."""
    a = np.asarray(open_ok, dtype=bool)
    b = np.asarray(closed_ok, dtype=bool)
    n = int(a.size)
    return {
        "n": n,
        "open": int(a.sum()),
        "closed": int(b.sum()),
        "both": int((a & b).sum()),
        "neither": int((~a & ~b).sum()),
        "only_open": int((a & ~b).sum()),
        "only_closed": int((~a & b).sum()),
        "open_rate": float(a.mean()) if n else float("nan"),
        "closed_rate": float(b.mean()) if n else float("nan"),
    }


def open_closed_rates(sim, plan, controller, params_list, seeds) -> dict:
    """Executions of ``plan`` without and with ``controller`` on the same draws: run ``i``
    uses ``params_list[i]`` and sensing seed ``seeds[i]`` in both. Returns
    :func:`paired_outcomes` plus the outcome counts of each loop (``open_outcomes``,
    ``closed_outcomes``; :data:`riskplan.control.lqg.OUTCOMES`)."""
    from riskplan.control.lqg import OUTCOMES, execute

    res = {"open": [], "closed": []}
    for params, sd in zip(params_list, seeds):
        for kind, ctrl in (("open", None), ("closed", controller)):
            ex = execute(sim, plan, ctrl, params, seed=np.random.default_rng(sd), keep_states=False)
            res[kind].append(ex.outcome)
    out = paired_outcomes(
        [o == "success" for o in res["open"]], [o == "success" for o in res["closed"]]
    )
    for kind in ("open", "closed"):
        out[f"{kind}_outcomes"] = {o: res[kind].count(o) for o in OUTCOMES}
    return out


def claims(cases: dict) -> dict:
    """The paper's Fig. 6 claims checked on measured rates (§V-A).

    * ``ours_highest[case]``: ours has a strictly higher rate than every other applicable
      method; ``ours_tied[case]``: ours shares the highest rate with at least one other
      method (a tie is reported as a tie, not as "highest"); ``ours_highest_all``: strictly
      highest in every case; ``ours_separated[case]`` whether its Wilson interval lies
      above every other method's.
    * "without LQG-MP: 34 % better than RRT with deformations and 17 % worse than the
      complete method, averaged over cases": the paper does not say whether percent points
      or relative change; both readings, on the rates averaged over the cases:
      ``points = 100 (r̄_a − r̄_b)`` and ``relative = 100 (r̄_a / r̄_b − 1)``.
    """
    highest, tied, separated = {}, {}, {}
    for c, ms in cases.items():
        ours = ms["ours"]
        others = [v for m, v in ms.items() if m != "ours" and v is not None]
        best_other = max((o["rate"] for o in others), default=-1.0)
        highest[c] = ours["rate"] > best_other
        tied[c] = ours["rate"] == best_other
        separated[c] = all(ours["low"] > o["high"] for o in others)

    def mean_rate(m):
        return float(np.mean([ms[m]["rate"] for ms in cases.values()]))

    r_rrt, r_ns, r_ours = mean_rate("rrt"), mean_rate("ours_no_select"), mean_rate("ours")

    def rel(a, b):
        return None if b == 0 else 100.0 * (a / b - 1.0)

    return {
        "ours_highest": highest,
        "ours_tied": tied,
        "ours_highest_all": all(highest.values()),
        "ours_separated": separated,
        "mean_rate": {"rrt": r_rrt, "ours_no_select": r_ns, "ours": r_ours},
        "no_select_vs_rrt": {
            "points": 100.0 * (r_ns - r_rrt),
            "relative": rel(r_ns, r_rrt),
            "paper": 34.0,
        },
        "no_select_vs_ours": {
            "points": 100.0 * (r_ns - r_ours),
            "relative": rel(r_ns, r_ours),
            "paper": -17.0,
        },
    }


def highest_verdict(cl: dict) -> str:
    """ "ours highest in every case": yes only when strictly highest in every case; ties
    are named as ties (``cl`` from :func:`claims`)."""
    strict = cl["ours_highest"]
    ties = cl.get("ours_tied", {})
    if cl["ours_highest_all"]:
        return "yes"
    parts = []
    tied = [c for c, t in ties.items() if t]
    lower = [c for c, ok in strict.items() if not ok and not ties.get(c)]
    if tied:
        parts.append("tied for highest in " + ", ".join(tied))
    if lower:
        parts.append("below another method in " + ", ".join(lower))
    return "no (" + "; ".join(parts) + ")"


# ---- Figs. 4, 5 and 7(c-f): single executions with and without feedback -----------------

#: The single executions of the paper's Figs. 4, 5, 7(c-f): ``(figure, scenario, case used
#: for the controller, parameter change, caption)``. "Much stiffer" (Fig. 5) is E = 150
#: (three times the planning value; the paper gives no number). Fig. 7(c, d) "variation
#: in material parameters": E = 35 (two standard deviations of case 2 below the mean,
#: a softer object that deforms more); Fig. 7(e, f) "mesh elements increased": 1000
#: elements (the top of case 4's range) instead of the planning mesh's 175.
SINGLE_RUNS = (
    ("fig4", "needle", "actuation", {"actuation": True}, "Fig. 4: actuation noise"),
    (
        "fig5",
        "needle",
        "material-high",
        {"youngs_modulus": 150.0},
        "Fig. 5: a much stiffer material (E = 150)",
    ),
    (
        "fig7cd",
        "manipulation",
        "material-high",
        {"youngs_modulus": 35.0},
        "Fig. 7(c, d): softer material (E = 35)",
    ),
    ("fig7ef", "manipulation", "mesh", {"n_elements": 1000}, "Fig. 7(e, f): a 1000-element mesh"),
)


def single_executions(name: str, plans_and_controllers: dict, *, seed: int = 0) -> dict:
    """Executions of the ``ours`` plan of ``name`` without and with feedback for the
    :data:`SINGLE_RUNS` of that scenario.

    ``plans_and_controllers[case] = (plan, controller)``. Returns ``{fig: {"open": Execution,
    "closed": Execution, "params": SimParams, "caption": str}}`` (states kept for plots).
    """
    from riskplan.control.lqg import execute
    from riskplan.scenarios.registry import make_scenario

    out = {}
    for fig, scen, case, change, caption in SINGLE_RUNS:
        if scen != name or case not in plans_and_controllers:
            continue
        sim = make_scenario(name, case)
        plan, ctrl = plans_and_controllers[case]
        change = dict(change)
        params = sim.nominal_params
        if change.pop("actuation", False):
            params = sim.distribution.sample(_seed_for(seed, fig, "actuation"))
        params = params.replace(**change)
        gen_seed = _seed_for(seed, fig, "sensing")
        out[fig] = {
            "open": execute(sim, plan, None, params, seed=gen_seed),
            "closed": execute(sim, plan, ctrl, params, seed=gen_seed),
            "params": params,
            "caption": caption,
            "sim": sim,
        }
    return out


def _feedback_rates(name, scale, store, chosen, plans, sims, seed, pmap, report, pre=None) -> dict:
    """``{figure: paired summary}`` of :mod:`riskplan.app.reproduce.feedback` for the conditions
    of scenario ``name`` whose case ran: the ``ours`` plan of that case executed open and
    closed loop on ``scale.n_feedback`` common draws, in stored batches (resumable)."""
    from riskplan.app.reproduce.feedback import CONDITIONS, feedback_batch, paired_summary
    from riskplan.parallel import spawn_seeds

    n, bs = int(scale.n_feedback), scale.batch_size
    figs = [f for f, c in CONDITIONS.items() if c.scenario == name and (c.case, "ours") in chosen]
    if n == 0 or not figs:
        return {}
    n_batches = -(-n // bs)
    items = [(f, b) for f in figs for b in range(n_batches)]
    pre = pre or f"fig6.{name}"
    key = {it: f"{pre}.feedback.{it[0]}.b{it[1]:05d}" for it in items}
    rows = {it: store.get(key[it]) for it in items}
    todo = [it for it in items if rows[it] is None]
    seeds = {f: spawn_seeds(_seed_for(seed, name, "feedback", f), n) for f in figs}
    done = len(items) - len(todo)
    report(f"{name}: open vs closed loop", done * bs, len(items) * bs)

    def task(it):
        f, b = it
        case = CONDITIONS[f].case
        s, j, sel = chosen[case, "ours"]
        return (sims[case], plans[s][j], sel["controller"], f, seeds[f][b * bs : (b + 1) * bs])

    for i, res in pmap(feedback_batch, [task(it) for it in todo]):
        rows[todo[i]] = res
        store.put(key[todo[i]], res)
        done += 1
        report(f"{name}: open vs closed loop", done * bs, len(items) * bs)
    out = {}
    for f in figs:
        summary = paired_summary([r for b in range(n_batches) for r in rows[f, b]])
        case = CONDITIONS[f].case
        _set, j, sel = chosen[case, "ours"]
        summary.update(
            caption=CONDITIONS[f].caption,
            case=case,
            candidate=j,
            controller_error=sel.get("error"),
        )
        out[f] = summary
    return out


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
        this process and of its finished workers.
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
    import resource
    import time

    from riskplan.app.store import ResultStore
    from riskplan.errors import InvalidInputError
    from riskplan.io import write_json_atomic
    from riskplan.parallel import TaskPool

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
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    store = ResultStore(
        out / "store",
        {"figure": "fig6", "scenario": scenario, "sizes": asdict(scale), "seed": seed},
    )
    t0 = time.perf_counter()
    stages: dict = {}

    def tracked(stage, done, total):
        now = time.perf_counter() - t0
        st = stages.setdefault(stage, {"start_s": now, "end_s": now, "total": total})
        st["end_s"] = now
        st["done"] = done
        if progress is not None:
            progress(stage, done, total)

    with TaskPool("local", workers) as pool:
        res = run_scenario(
            scenario,
            scale,
            store,
            seed=seed,
            backend="local",
            workers=workers,
            pool=pool,
            progress=tracked,
            disturbance=disturbance,
        )
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    tag = scenario + ("_disturbance" if disturbance else "")
    write_json_atomic(out / f"fig6_{tag}.json", res)
    write_json_atomic(
        out / f"timings_{tag}.json",
        {
            "wall_s": time.perf_counter() - t0,
            "cpu_s_self": own.ru_utime + own.ru_stime,
            "cpu_s_workers": kids.ru_utime + kids.ru_stime,
            "stages": stages,
        },
    )
    return res
