"""The 3-D needle under uncertainty (issue: beyond the deformable paper's future work):
simulator RRT candidates, LQG-MP selection in 3-D, and the measurements — LQG-MP
``P(success)`` (truncation, per-step, sigma, sampling, the linear model, particles) against
closed-loop executions (within ±2 points of all of them, e.g. 10,000, and inside the 95 %
Wilson interval of the first, e.g. 1000), and the targeting error of closed vs open loop
on common draws — plus the interactive plotly figure and the outputs of
``riskplan plan needle3d``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

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
    "needle3d_figure",
    "plan_needle3d",
    "write_outputs",
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
#: it serves — within ±2 points (:data:`~riskplan.app.reproduce.needle3d_checks.CHECK_POINTS`)
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
    ``structured``: the structured linearisation's check (:func:`~riskplan.app.reproduce.needle3d_checks.measure_structured`);
    ``n_open``: the first draws also executed open loop (the rest closed loop only: ``n``
    counts all), with ``closed_first``/``closed_first_ci``/``closed_first_cpu_s`` the closed
    loop on them (:func:`~riskplan.app.reproduce.needle3d_checks.fill_rates`; the targeting
    errors are on them too); ``checks``: each estimate within
    :data:`~riskplan.app.reproduce.needle3d_checks.CHECK_POINTS` of ``closed/n`` and inside
    ``closed_first_ci`` (:func:`~riskplan.app.reproduce.needle3d_checks.accuracy_checks`);
    ``speed``: the executions' CPU over each prediction's
    (:func:`~riskplan.app.reproduce.needle3d_checks.speed_ratios`)."""

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
    """Every candidate's controller (linearised along it with ``sim.distribution``) and
    its LQG-MP estimates by each of :data:`ESTIMATORS`: the goal test exact (a target that
    is not an ellipsoid, and the comparison in ``PlanRow.draws``: in batches of
    ``n_goal_samples`` draws to a standard error of ``goal_se``, at most
    :data:`MAX_GOAL_SAMPLES`; ``None``: one batch), ``"sampling"`` with ``n_goal_samples``
    trajectories, ``"particles"`` to :data:`PARTICLES_SE` (batches of
    :data:`PARTICLES_BATCH`, at most :data:`MAX_PARTICLES`). Returns ``(controllers, rows)``;
    a candidate whose linearisation fails gets ``None`` and estimates of 0. CPU seconds
    in ``estimate_cpu_s``: ``"truncation"`` the prediction given the controller (the
    second-order model and the truncation on it), ``"truncation+linearise"`` with the
    linearisation and the controller's gains, ``"linear"`` the linear model's truncation,
    ``"truncation_repeats"`` two more runs of the prediction (a list); ``"per-step"``,
    ``"sigma"``, ``"sampling"`` and ``"particles"`` the second-order model and the method."""
    from riskplan.app.reproduce.needle3d_checks import actuation_cov, drawn_estimate, repeat_cpu
    from riskplan.control.lqgmp3d import lqgmp_3d
    from riskplan.control.lqgmp3d_moments import second_order_model
    from riskplan.control.lqgmp3d_particles import lqgmp_particles
    from riskplan.parallel import spawn_seeds
    from riskplan.tissue_planning.select import _FAILURES, evaluate_plan

    W = actuation_cov(sim)
    ctrls, rows = [], []
    kw = dict(n_goal_samples=n_goal_samples)
    kw_se = dict(kw, goal_se=goal_se, max_goal_samples=MAX_GOAL_SAMPLES)
    for i, (plan, s) in enumerate(zip(plans, spawn_seeds(seed, len(plans)))):
        c0 = time.process_time()
        try:
            ctrl, _ = evaluate_plan(
                sim, plan, method="truncation", n_samples=n_samples, seed=s, **kw
            )
        except _FAILURES as exc:
            log.warning("needle3d: candidate %d not linearised (%s)", i, exc)
            ctrls.append(None)
            rows.append(PlanRow(i, plan.n_steps, dict.fromkeys(ESTIMATORS, 0.0), {}))
            continue
        c_lin = time.process_time() - c0
        c0 = time.process_time()
        lqgmp_3d(sim, plan, ctrl, method="truncation", seed=s, **kw)  # evaluate_plan's share
        c_lin -= time.process_time() - c0
        c0 = time.process_time()
        got = {"linear": lqgmp_3d(sim, plan, ctrl, method="truncation", seed=s, **kw_se)}
        cpu = {"linear": time.process_time() - c0}
        c0 = time.process_time()
        mo = None if W is None else second_order_model(sim, plan, ctrl, W)
        c_model = time.process_time() - c0
        c0 = time.process_time()
        got["truncation"] = lqgmp_3d(
            sim, plan, ctrl, method="truncation", seed=s, moments=mo, **kw_se
        )
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
        ctrls.append(ctrl)
        rows.append(
            PlanRow(
                i,
                plan.n_steps,
                {m: got[m].p_success if m in got else nan for m in ESTIMATORS},
                secs,
                estimate_cpu_s=cpu,
                estimate_n={m: got[m].n_goal_samples if m in got else 0 for m in ESTIMATORS},
                estimate_se={m: got[m].p_success_se if m in got else nan for m in ESTIMATORS},
                draws=drawn,
            )
        )
    return ctrls, rows


def measure_plan(
    sim, plan, controller, row: PlanRow, *, n: int, seed=0, n_open: int | None = None
) -> PlanRow:
    """Closed-loop executions of ``plan`` on ``n`` draws (parameters and actuation from
    ``sim.distribution``, the closed loop's sensing noise from the same seed) and open-loop
    ones on the first ``n_open`` of them (``None``: all ``n``; common draws): success counts,
    Wilson intervals, outcomes, and the targeting error (final distance of the world tip to
    the deformed target centre), in one process
    (:func:`~riskplan.app.reproduce.needle3d_checks.execute_draws`,
    :func:`~riskplan.app.reproduce.needle3d_checks.fill_rates`)."""
    from riskplan.app.reproduce.needle3d_checks import execute_draws, fill_rates
    from riskplan.parallel import spawn_seeds

    t0 = time.perf_counter()
    n_open = n if n_open is None else min(int(n_open), n)
    part = execute_draws((sim, plan, controller, spawn_seeds(seed, n), n_open))
    fill_rates(row, [part], n_open)
    row.mc_s = time.perf_counter() - t0
    return row


@dataclass
class Needle3DResult:
    """What :func:`plan_needle3d` returns: the candidates, the rows (ranked by the
    truncation estimate), the selected index, its controller, timings and the scale."""

    plans: list
    rows: list
    best: int
    controller: object
    timings: dict
    settings: dict


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
    """Simulator RRT candidates for the 3-D needle, LQG-MP (truncation) selection and, with
    ``check_runs > 0``, ``check_runs`` closed-loop executions of the selected plan and of
    ``check_plans − 1`` more spread over the ranking, open-loop ones on the first
    ``open_runs`` of the same draws (``None``: all; ``structured``: the structured
    linearisation's controller on those too,
    :func:`~riskplan.app.reproduce.needle3d_checks.measure_structured`), split into tasks
    of :data:`~riskplan.app.reproduce.needle3d_checks.DRAWS_PER_TASK` draws over the
    workers; each checked row gets its accuracy checks and speed ratios (:class:`PlanRow`
    ``checks``, ``speed``). ``frame``: the reduced state the
    linearisation, the controllers and LQG-MP read (:data:`riskplan.scenarios.needle3d.FRAMES`;
    the RRT plans in the world frame, its plans are reframed); ``result.plans`` stay in
    the world frame."""
    from riskplan._validation import check_count
    from riskplan.scenarios.registry import scenario_from_config
    from riskplan.tissue_planning.rrt import RRTOptions, rrt_plans
    from riskplan.tissue_planning.select import evenly_spaced_ranks

    check_count(check_runs, "check_runs", 0, integral=True)
    if open_runs is not None:
        check_count(open_runs, "open_runs", 1, integral=True)
    sim = scenario_from_config("needle3d", config, case)
    t0 = time.perf_counter()
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
        # the candidates are distinct plans (rrt_plans keeps a path repeated by several trees once)
        usable = [r for r in ranked if ctrls[r.index] is not None]
        chosen = [
            usable[k] for k in evenly_spaced_ranks(len(usable), min(check_plans, len(usable)))
        ]
        from riskplan.app.reproduce.needle3d_checks import measure_checked

        done = measure_checked(
            sim,
            plans,
            ctrls,
            chosen,
            n=check_runs,
            n_open=open_runs,
            seed=seed + 1,  # the same draws for each plan
            structured=structured,
            workers=workers,
        )
        by_index = {r.index: r for r in done}
        ranked = [by_index.get(r.index, r) for r in ranked]
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


def needle3d_figure(sim, plans, executed=(), highlight: int | None = None):
    """An interactive plotly figure: the block's outline, the obstacles and the target (in
    the undeformed configuration, translucent), the candidate plans' world tip paths (the
    highlighted one thick) and executed paths (``executed``: ``(T, 3)`` arrays)."""
    import plotly.graph_objects as go

    from riskplan.geometry3d import ConvexBody

    cfg = sim.config
    fig = go.Figure()
    sx, sy, sz = cfg.size
    corners = np.array([[x, y, z] for x in (0, sx) for y in (0, sy) for z in (0, sz)])
    edges = [
        (0, 1),
        (0, 2),
        (0, 4),
        (1, 3),
        (1, 5),
        (2, 3),
        (2, 6),
        (3, 7),
        (4, 5),
        (4, 6),
        (5, 7),
        (6, 7),
    ]
    for a, b in edges:
        fig.add_trace(
            go.Scatter3d(
                x=corners[[a, b], 0],
                y=corners[[a, b], 1],
                z=corners[[a, b], 2],
                mode="lines",
                line=dict(color="grey"),
                showlegend=False,
            )
        )
    y0 = sim.initial_state()
    for i, body in enumerate(sim._bodies(y0)):
        pts = ConvexBody(body.kind, body.centre, body.A).surface(10)
        fig.add_trace(
            go.Mesh3d(
                x=pts[:, 0],
                y=pts[:, 1],
                z=pts[:, 2],
                alphahull=0,
                opacity=0.3,
                color="green" if i == len(sim._bodies(y0)) - 1 else "red",
                name="target" if i == len(sim._bodies(y0)) - 1 else f"obstacle {i}",
            )
        )
    for k, plan in enumerate(plans):
        p = plan.reduced[:, :3]
        fig.add_trace(
            go.Scatter3d(
                x=p[:, 0],
                y=p[:, 1],
                z=p[:, 2],
                mode="lines",
                line=dict(
                    width=7 if k == highlight else 2,
                    color="blue" if k == highlight else "lightblue",
                ),
                name=f"plan {k}",
                showlegend=k == highlight,
            )
        )
    for j, path in enumerate(executed):
        path = np.asarray(path)
        fig.add_trace(
            go.Scatter3d(
                x=path[:, 0],
                y=path[:, 1],
                z=path[:, 2],
                mode="lines",
                line=dict(width=2, color="orange"),
                name="executed",
                showlegend=j == 0,
            )
        )
    fig.update_layout(
        scene=dict(aspectmode="data"),
        margin=dict(l=0, r=0, t=30, b=0),
        title="3-D needle: tissue block, obstacles, target, plans, executions",
    )
    return fig


def write_outputs(result: Needle3DResult, out, *, n_executed: int = 10, seed: int = 0) -> dict:
    """``selected.npz`` (controls, world path), ``summary.json`` (rows, timings, settings)
    and ``needle3d.html`` (the figure with ``n_executed`` closed-loop executions of the
    selected plan; plotly.js embedded, so the page works offline). Atomic writes."""
    from riskplan.control.lqg import execute
    from riskplan.io import atomic_path, write_json_atomic, write_text_atomic
    from riskplan.scenarios.registry import scenario_from_config

    out = Path(out)
    sim = scenario_from_config("needle3d", None, result.settings["case"])
    frame = result.settings.get("frame", "world")
    run_sim = sim.with_frame(frame)  # the frame the controller reads
    plan = result.plans[result.best]
    files = {}
    with atomic_path(out / "selected.npz", suffix=".npz") as tmp:
        np.savez(tmp, controls=plan.controls, path=plan.reduced[:, :3])
    files["selected"] = out / "selected.npz"
    write_json_atomic(
        out / "summary.json",
        {
            "best": result.best,
            "rows": [r.as_dict() for r in result.rows],
            "timings": result.timings,
            "settings": result.settings,
        },
    )
    files["summary"] = out / "summary.json"
    executed = []
    if result.controller is not None:
        gen = np.random.default_rng(seed)
        run_plan = plan.reframed(run_sim)
        for _ in range(n_executed):
            ex = execute(run_sim, run_plan, result.controller, sim.sample_params(gen), seed=gen)
            executed.append(sim.path(ex.states))
    fig = needle3d_figure(sim, result.plans, executed, highlight=result.best)
    write_text_atomic(out / "needle3d.html", fig.to_html(include_plotlyjs=True))
    files["figure"] = out / "needle3d.html"
    return files


#: sizes of the ``reproduce`` stage ``needle3d`` by scale name
NEEDLE3D_SCALES = {
    "smoke": dict(n_plans=2, check_runs=0, check_plans=1, max_iterations=400),
    # 10,000 closed-loop executions per checked plan (the check within ±2 points), open loop and
    # the structured check on the first 1000 of them (the Wilson check at 1000, the targeting
    # error): about 25 core-minutes in all
    "paper": dict(
        n_plans=30,
        check_runs=10_000,
        open_runs=1000,
        check_plans=6,
        max_iterations=600,
        structured=True,
    ),
}


def run_needle3d(out, scale: str = "smoke", *, seed: int = 0, case: str = "actuation") -> dict:
    """The ``reproduce`` stage ``needle3d``: :func:`plan_needle3d` at the sizes of
    :data:`NEEDLE3D_SCALES` (``"smoke"`` unless ``scale`` is ``"paper"``), its outputs in
    ``out/needle3d/`` (:func:`write_outputs`, the interactive figure included). Returns what
    ``results.json`` holds: rows, timings, settings and the figure's path relative to ``out``."""
    size = NEEDLE3D_SCALES["paper" if scale == "paper" else "smoke"]
    res = plan_needle3d(case, seed=seed, **size)
    folder = Path(out) / "needle3d"
    folder.mkdir(parents=True, exist_ok=True)
    files = write_outputs(res, folder, seed=seed)
    return {
        "best": res.best,
        "rows": [r.as_dict() for r in res.rows],
        "timings": res.timings,
        "settings": res.settings,
        "figure": str(Path("needle3d") / files["figure"].name),
    }
