"""Speed of ``riskplan reproduce`` (issue 12): ``riskplan bench reproduce --json``.

* ``needle_executions_per_s`` / ``manipulation_executions_per_s`` — simulated executions
  per second on one core, in the mix of Fig. 6: one plan (an RRT candidate) with its LQG
  controller, for each of the five uncertainty cases the same seeds executed once open
  loop and once closed loop (draw of ``s``, true simulator, sensing noise, Kalman filter,
  collision and goal checks; the mesh case builds a new mesh for most draws, as it does in
  Fig. 6). Planning, linearisation and LQG-MP are excluded (they are per plan, not per
  execution). The paper-scale Fig. 6 has 20,000 executions per scenario
  (4 methods × 5 cases × 1000; 15,000 for manipulation, where one method does not apply).
Rates and per-candidate costs are measured in CPU time of this (single-threaded) process
(``time.process_time``), so on a machine shared with other jobs they still describe one
core, not the share of it the scheduler gave.

* ``needle_executions_per_s_shared_draws`` / ``manipulation_executions_per_s_shared_draws``
  — the same rate as Fig. 6 executes now: each case's draws in one task on a freshly
  unpickled scenario, four runs of the plan (two open, two closed loop) on each draw, so a
  draw's FEM model (and in the mesh case its mesh) is built once for the four
  (:func:`riskplan.app.reproduce.deformable.execute_methods`).
* ``smoke_all_s`` — wall-clock seconds of ``riskplan reproduce --paper all --scale smoke``
  (local process pool, all cores) in a fresh folder; ``None`` with ``--quick``.
* ``*_rrt_s_per_candidate`` (one tree grown for one plan: an upper bound, trees of the
  paper scale collect 10 plans each) and ``*_select_s_per_candidate_case`` (linearisation
  with 16 parameter draws + LQG + LQG-MP with 2000 goal samples, the paper scale's sizes).
* ``cpu`` and ``cores``: the machine.
"""

from __future__ import annotations

import os
import tempfile
import time

from riskplan.bench import cpu_model


def executions_per_s(name: str, n_per_case: int, seed: int = 0, costs: dict | None = None) -> float:
    """Executions per second of scenario ``name`` on one core (module docstring).

    ``costs``, if given, receives ``rrt_s`` (one candidate, one tree) and ``select_s`` (mean
    seconds of one candidate's linearisation + LQG + LQG-MP under one case), the per-plan
    costs that, with the execution rate, give the paper-scale estimate in docs/reproduce.md."""
    from riskplan.app.reproduce.deformable import EVAL_CASES, evaluate_candidate, execute_batch
    from riskplan.parallel import spawn_seeds
    from riskplan.scenarios.registry import make_scenario
    from riskplan.tissue_planning.rrt import RRTOptions, rrt_plans

    base = make_scenario(name)
    t0 = time.process_time()
    plans, _ = rrt_plans(base, 1, seed=seed, options=RRTOptions(plans_per_tree=1), backend="serial")
    t_rrt = time.process_time() - t0
    plan = plans[0]
    elapsed, count, t_select = 0.0, 0, []
    for case in EVAL_CASES:
        sim = make_scenario(name, case)
        t0 = time.process_time()
        ctrl = evaluate_candidate((sim, plan, 16, 2000, seed))["controller"]
        t_select.append(time.process_time() - t0)
        seeds = spawn_seeds(seed, n_per_case + 1)
        execute_batch(
            (sim, plan, ctrl, seeds[:1])
        )  # warm-up: FEM model of the planning mesh, imports
        t0 = time.process_time()
        execute_batch((sim, plan, None, seeds[1:]))
        execute_batch((sim, plan, ctrl, seeds[1:]))
        elapsed += time.process_time() - t0
        count += 2 * n_per_case
    if costs is not None:
        costs["shared_draws_executions_per_s"] = _shared_draws_rate(name, plan, seed, n_per_case)
        costs["rrt_s"] = t_rrt
        costs["select_s"] = sum(t_select[1:]) / max(
            1, len(t_select) - 1
        )  # the first one pays imports and JIT
    return count / elapsed


def _shared_draws_rate(name: str, plan, seed: int, n_per_case: int) -> float:
    """Executions per CPU second as Fig. 6 runs them now: per case one task of ``n_per_case``
    draws on a freshly unpickled scenario (as a pool worker receives it), the plan executed
    open loop twice and closed loop twice on each draw
    (:func:`riskplan.app.reproduce.deformable.execute_methods`: a draw's FEM model and mesh are
    built once for all four)."""
    import pickle

    from riskplan.app.reproduce.deformable import EVAL_CASES, evaluate_candidate, execute_methods
    from riskplan.parallel import spawn_seeds
    from riskplan.scenarios.registry import make_scenario

    elapsed, count = 0.0, 0
    for case in EVAL_CASES:
        sim = make_scenario(name, case)
        ctrl = evaluate_candidate((sim, plan, 16, 2000, seed))["controller"]
        # the draws the measure above executes (common random numbers: the two rates differ in
        # how the work is organised, not in the draws)
        seeds = spawn_seeds(seed, n_per_case + 1)[1:]
        runs = [(plan, None), (plan, None), (plan, ctrl), (plan, ctrl)]
        task = pickle.dumps((sim, runs, seeds))
        t0 = time.process_time()
        execute_methods(pickle.loads(task))
        elapsed += time.process_time() - t0
        count += len(runs) * n_per_case
    return count / elapsed


def run(quick: bool = False) -> dict:
    needle, manipulation = {}, {}
    out = {
        "needle_executions_per_s": executions_per_s("needle", 5 if quick else 40, costs=needle),
        "manipulation_executions_per_s": executions_per_s(
            "manipulation", 2 if quick else 10, costs=manipulation
        ),
        "needle_rrt_s_per_candidate": needle["rrt_s"],
        "needle_select_s_per_candidate_case": needle["select_s"],
        "needle_executions_per_s_shared_draws": needle["shared_draws_executions_per_s"],
        "manipulation_executions_per_s_shared_draws": manipulation["shared_draws_executions_per_s"],
        "manipulation_rrt_s_per_candidate": manipulation["rrt_s"],
        "manipulation_select_s_per_candidate_case": manipulation["select_s"],
        "smoke_all_s": None,
        "cpu": cpu_model(),
        "cores": len(os.sched_getaffinity(0))
        if hasattr(os, "sched_getaffinity")
        else os.cpu_count(),
    }
    if not quick:
        from riskplan.app.reproduce.pipeline import reproduce

        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            reproduce(tmp, paper="all", scale="smoke", backend="local")
            out["smoke_all_s"] = time.perf_counter() - t0
    return out
