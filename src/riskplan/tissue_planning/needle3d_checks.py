"""Checks of the 3-D needle's planning (:mod:`riskplan.tissue_planning.needle3d`) beside
its estimates: the prediction with the goal test drawn instead of exact, warm repeats of the
prediction's timing, the structured linearisation's controller against executions, and the
executions themselves — split into tasks of consecutive draws so that 2 worker processes
balance — with the accuracy checks the estimates are judged by (within
:data:`CHECK_POINTS` of the closed-loop rate of all executions; inside the 95 % Wilson
interval of the first ``n_open``) and their speed ratios.

``actuation_cov``, ``drawn_estimate`` and ``repeat_cpu`` are helpers of
:func:`~riskplan.tissue_planning.needle3d.evaluate_candidates`."""

from __future__ import annotations

import time

import numpy as np

from riskplan.errors import InvalidInputError

__all__ = [
    "CHECK_POINTS",
    "DRAWS_PER_TASK",
    "accuracy_checks",
    "execute_draws",
    "fill_rates",
    "measure_checked",
    "measure_structured",
    "speed_ratios",
]

#: the tolerance of the check against many executions (issue #22, item 5: predicted
#: P(success) "within ±2 points of ≥ 10,000" closed-loop executions)
CHECK_POINTS = 0.02


def actuation_cov(sim):
    """``Σ_w`` when the case's only uncertainty is the actuation noise (the second-order
    model's scope), else ``None`` (material, mesh and force draws: the linear model)."""
    from riskplan.scenarios.uncertainty import ActuationNoise

    dist = sim.distribution
    return np.asarray(dist.cov, dtype=np.float64) if isinstance(dist, ActuationNoise) else None


def repeat_cpu(sim, plan, ctrl, seed, W, kw_se: dict, n: int = 2) -> list:
    """CPU seconds of ``n`` more runs of the prediction (the second-order model and the
    truncation on it), after the first: the first run of a plan also fills the tissue's
    per-node caches for the points the statistical linearisation visits."""
    from riskplan.control.lqgmp3d import lqgmp_3d
    from riskplan.control.lqgmp3d_moments import second_order_model

    out = []
    for _ in range(n):
        c0 = time.process_time()
        mo = None if W is None else second_order_model(sim, plan, ctrl, W)
        lqgmp_3d(sim, plan, ctrl, method="truncation", seed=seed, moments=mo, **kw_se)
        out.append(time.process_time() - c0)
    return out


def drawn_estimate(sim, plan, ctrl, seed, moments, c_model: float, kw_se: dict) -> dict:
    """The truncation estimate (on ``moments`` and on the linear model) with the goal test
    drawn to :data:`~riskplan.tissue_planning.needle3d.GOAL_SE` instead of exact, for comparison: ``{"truncation": p, "n": n,
    "se": s.e., "cpu_s": the prediction's CPU seconds with the draws, "linear": p}``."""
    from riskplan.control.lqgmp3d import lqgmp_3d

    c0 = time.process_time()
    tr = lqgmp_3d(
        sim, plan, ctrl, method="truncation", seed=seed, moments=moments, goal="draws", **kw_se
    )
    cpu = c_model + time.process_time() - c0
    lin = lqgmp_3d(sim, plan, ctrl, method="truncation", seed=seed, goal="draws", **kw_se)
    return {
        "truncation": tr.p_success,
        "n": tr.n_goal_samples,
        "se": tr.p_success_se,
        "cpu_s": cpu,
        "linear": lin.p_success,
    }


def measure_structured(sim, plan, row, *, n: int, seed=0):
    """The structured linearisation's check (the actuation case; nothing otherwise): the
    controller from :func:`~riskplan.control.lqgmp3d_moments.structured_linearization`
    (the material step's closed form times the tissue's Jacobian, no simulator runs), its
    prediction (second-order model, truncation, exact goal test) and ``n`` closed-loop
    executions on the draws of
    :func:`~riskplan.tissue_planning.needle3d.measure_plan`.

    Parameters
    ----------
    sim : riskplan.scenarios.Needle3DScenario
        The scenario; with a case other than the actuation noise, nothing is done.
    plan : riskplan.control.NominalPlan
        The plan checked.
    row : riskplan.tissue_planning.needle3d.PlanRow
        The plan's row; ``row.structured`` is set in place.
    n : int
        Closed-loop executions.
    seed : int or numpy.random.SeedSequence, optional
        Master seed of the draws (:func:`~riskplan.parallel.spawn_seeds` ``(seed, n)``).

    Returns
    -------
    riskplan.tissue_planning.needle3d.PlanRow
        ``row``, with ``row.structured``: ``prediction``, ``closed``, ``closed_ci``,
        ``lin_cpu_s`` (linearisation and gains), ``cpu_s`` (the prediction),
        ``closed_cpu_s`` (empty for a case it does not apply to).
    """
    from riskplan.collision import binomial_interval
    from riskplan.control.lqg import lqg_controller
    from riskplan.control.lqgmp3d import lqgmp_3d
    from riskplan.control.lqgmp3d_moments import second_order_model, structured_linearization
    from riskplan.parallel import spawn_seeds

    W = actuation_cov(sim)
    if W is None:
        return row
    c0 = time.process_time()
    ctrl = lqg_controller(structured_linearization(sim, plan, W))
    c1 = time.process_time()
    pred = lqgmp_3d(
        sim, plan, ctrl, method="truncation", moments=second_order_model(sim, plan, ctrl, W)
    )
    c2 = time.process_time()
    runs = execute_draws((sim, plan, ctrl, spawn_seeds(seed, n), 0))["closed"]
    k = sum(outcome == "success" for outcome, _, _ in runs)
    lo, hi = binomial_interval(k, n)
    row.structured = dict(
        prediction=pred.p_success,
        closed=k,
        closed_ci=(float(lo), float(hi)),
        lin_cpu_s=c1 - c0,
        cpu_s=c2 - c1,
        closed_cpu_s=time.process_time() - c2,
    )
    return row


def execute_draws(args) -> dict:
    """One task of the executions (:func:`~riskplan.tissue_planning.needle3d.measure_plan`):
    closed-loop executions on the draws of ``seeds`` (parameters and actuation from
    ``sim.distribution``, the sensing noise from the same generator) and open-loop ones on
    the first ``n_open`` of them (common draws).

    Parameters
    ----------
    args : tuple
        ``(sim, plan, controller, seeds, n_open)``: the scenario, the plan, its controller,
        the draws' seeds and the number of them also executed open loop (one argument, so
        that it maps over worker processes).

    Returns
    -------
    dict
        ``{"closed": [...], "open": [...], "closed_cpu_s": [...]}``: per draw ``(outcome,
        final distance of the world tip to the deformed target centre, distance of it from
        the plan's end, both relative to that centre)`` and the closed loop's CPU seconds.
    """
    from riskplan.control.lqg import execute

    sim, plan, controller, seeds, n_open = args
    rel_plan = plan.reduced[-1][:3] - sim.goal(plan.states[-1]).centre
    out = {"closed": [], "open": [], "closed_cpu_s": []}
    for j, s in enumerate(seeds):
        for mode, ctrl in (("closed", controller), ("open", None)):
            if mode == "open" and j >= n_open:
                continue
            c0 = time.process_time()
            gen = np.random.default_rng(s)
            ex = execute(sim, plan, ctrl, sim.sample_params(gen), seed=gen, keep_states=False)
            if mode == "closed":
                out["closed_cpu_s"].append(time.process_time() - c0)
            last = ex.states[-1]
            rel = last.pose[:3] - sim.goal(last).centre
            out[mode].append(
                (ex.outcome, float(np.linalg.norm(rel)), float(np.linalg.norm(rel - rel_plan)))
            )
    return out


def fill_rates(row, parts: list, n_open: int):
    """Put the tasks' executions into ``row``: ``n``, ``closed``, ``closed_ci`` over all
    draws; ``n_open``, ``open``, ``open_ci`` and ``closed_first``, ``closed_first_ci`` over
    the first ``n_open`` (common draws); outcomes; the targeting errors on the common draws;
    ``closed_cpu_s`` (all) and ``closed_first_cpu_s``.

    Parameters
    ----------
    row : riskplan.tissue_planning.needle3d.PlanRow
        The plan's row, filled in place.
    parts : list of dict
        The tasks' results (:func:`execute_draws`), in draw order.
    n_open : int
        Draws executed open loop (the first ones).

    Returns
    -------
    riskplan.tissue_planning.needle3d.PlanRow
        ``row``.

    Raises
    ------
    riskplan.errors.InvalidInputError
        When ``parts`` hold another number of open-loop executions than ``n_open``.
    """
    from riskplan.collision import binomial_interval

    closed = [r for part in parts for r in part["closed"]]
    opened = [r for part in parts for r in part["open"]]
    cpu = [c for part in parts for c in part["closed_cpu_s"]]
    n = len(closed)
    n_open = min(int(n_open), n)
    if len(opened) != n_open:
        raise InvalidInputError(
            f"fill_rates: {len(opened)} open-loop executions, expected {n_open}"
        )

    def rate(runs):
        k = sum(o == "success" for o, *_ in runs)
        lo, hi = binomial_interval(k, len(runs))
        return k, (float(lo), float(hi))

    row.n, row.n_open = n, n_open
    row.closed, row.closed_ci = rate(closed)
    row.closed_first, row.closed_first_ci = rate(closed[:n_open])
    row.open, row.open_ci = rate(opened)
    for mode, runs in (("closed", closed), ("open", opened)):
        outc = [o for o, *_ in runs]
        setattr(row, f"outcomes_{mode}", {o: outc.count(o) for o in sorted(set(outc))})
    for mode, runs in (("closed", closed[:n_open]), ("open", opened)):
        setattr(row, f"target_error_{mode}", float(np.mean([d for _, d, _ in runs])))
        setattr(row, f"end_error_{mode}", float(np.mean([e for *_, e in runs])))
    row.closed_cpu_s = float(sum(cpu))
    row.closed_first_cpu_s = float(sum(cpu[:n_open]))
    return row


def accuracy_checks(
    estimates: dict, k: int, n: int, k_first: int, n_first: int, points: float = CHECK_POINTS
) -> dict:
    """Each estimate against the executions: within ``points`` of the closed-loop rate of
    all of them, and inside the 95 % Wilson interval of the first ones.

    Parameters
    ----------
    estimates : dict
        Method -> predicted ``P(success)`` ``p``.
    k, n : int
        Successes of all closed-loop executions, and their number.
    k_first, n_first : int
        Successes of the first executions, and their number.
    points : float, optional
        The tolerance on ``|p − k/n|`` (:data:`CHECK_POINTS`).

    Returns
    -------
    dict
        ``{method: {"error": p − k/n, "within_points": |p − k/n| <= points,
        "inside_first": p in the 95 % Wilson interval of k_first of n_first}}`` (NaN
        estimates: ``False``).
    """
    from riskplan.collision import binomial_interval

    lo, hi = binomial_interval(k_first, n_first)
    out = {}
    for m, p in estimates.items():
        err = float(p) - k / n
        out[m] = {
            "error": err,
            "within_points": bool(abs(err) <= points),
            "inside_first": bool(lo <= p <= hi),
        }
    return out


def speed_ratios(estimate_cpu_s: dict, closed_cpu_s: float, closed_first_cpu_s: float) -> dict:
    """The executions' CPU seconds (all of them; the first ``n_open``) over each prediction's.

    Parameters
    ----------
    estimate_cpu_s : dict
        Method -> the prediction's CPU seconds (non-numbers, such as the lists of repeats,
        and zeros are left out).
    closed_cpu_s : float
        CPU seconds of all closed-loop executions.
    closed_first_cpu_s : float
        CPU seconds of the first ones.

    Returns
    -------
    dict
        ``{method: {"all": closed_cpu_s / cpu, "first": closed_first_cpu_s / cpu}}``.
    """
    return {
        m: {"all": closed_cpu_s / c, "first": closed_first_cpu_s / c}
        for m, c in estimate_cpu_s.items()
        if isinstance(c, float) and c > 0.0
    }


#: draws per task of the executions: tasks of equal size keep 2 workers balanced
DRAWS_PER_TASK = 1000


def _task(args):
    """A worker's task: ``("draws", ...)`` executions
    (:func:`~riskplan.tissue_planning.needle3d_checks.execute_draws`) or ``("structured",
    ...)`` the structured check of one plan."""
    kind, rest = args
    if kind == "draws":
        return execute_draws(rest)
    sim, plan, row, n, seed = rest
    return measure_structured(sim, plan, row, n=n, seed=seed).structured


def measure_checked(sim, plans, ctrls, chosen, *, n, n_open, seed, structured, workers):
    """The executions of the ``chosen`` rows' plans, ``n`` closed-loop draws each (open loop
    and the structured check on the first ``n_open``), in tasks of :data:`DRAWS_PER_TASK`
    draws over the workers (the heavier ones first); each row filled (:func:`fill_rates`),
    checked (:func:`accuracy_checks`) and timed (:func:`speed_ratios`, ``mc_s`` the wall
    seconds of all the executions).

    Parameters
    ----------
    sim : riskplan.scenarios.Needle3DScenario
        The scenario, in the frame the controllers read.
    plans : list of riskplan.control.NominalPlan
        All candidates (indexed by ``row.index``).
    ctrls : list
        Their controllers.
    chosen : list of riskplan.tissue_planning.needle3d.PlanRow
        The rows checked.
    n : int
        Closed-loop executions per plan (the same draws for every plan).
    n_open : int
        The first draws also executed open loop (and the structured check's).
    seed : int or numpy.random.SeedSequence
        Master seed of the draws (:func:`~riskplan.parallel.spawn_seeds` ``(seed, n)``).
    structured : bool
        Whether to run the structured check (:func:`measure_structured`).
    workers : int or None
        Worker processes, as :func:`~riskplan.parallel.map_tasks` takes them (1: in this
        process).

    Returns
    -------
    list of riskplan.tissue_planning.needle3d.PlanRow
        The ``chosen`` rows, filled in place, in their order.
    """
    from riskplan.parallel import map_tasks, spawn_seeds

    seeds = spawn_seeds(seed, n)  # the same draws for every plan
    heavy, light, where = [], [], []
    for r in chosen:
        sim_plan_ctrl = (sim, plans[r.index], ctrls[r.index])
        if structured:
            heavy.append(("structured", (sim, plans[r.index], r, n_open, seed)))
            where.append((r.index, "structured", len(heavy) - 1))
        for a in range(0, n, DRAWS_PER_TASK):
            chunk = seeds[a : a + DRAWS_PER_TASK]
            task = ("draws", (*sim_plan_ctrl, chunk, max(0, min(n_open - a, len(chunk)))))
            (heavy if a < n_open else light).append(task)
            where.append((r.index, "draws", len(heavy) - 1 if a < n_open else -len(light)))
    t0 = time.perf_counter()
    backend = "local" if (workers or 0) != 1 else "serial"
    done = map_tasks(_task, heavy + light, backend=backend, workers=workers, chunksize=1)
    wall = time.perf_counter() - t0
    out = []
    for r in chosen:
        parts = []
        for idx, kind, j in where:
            if idx != r.index:
                continue
            got = done[j] if j >= 0 else done[len(heavy) + (-j - 1)]
            if kind == "structured":
                r.structured = got
            else:
                parts.append(got)
        fill_rates(r, parts, n_open)
        r.mc_s = wall
        r.checks = accuracy_checks(r.estimates, r.closed, r.n, r.closed_first, r.n_open)
        r.speed = speed_ratios(r.estimate_cpu_s, r.closed_cpu_s, r.closed_first_cpu_s)
        out.append(r)
    return out
