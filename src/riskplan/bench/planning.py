"""``riskplan bench planning``: the chest-cavity planner (MDN paper section V, Fig. 7).

Keys (issue 10): ``bound_reduction`` (relative reduction of the eq.-10 bound after 50 BO
iterations, median over 5 optimiser seeds on the default scene's nominal trajectory),
``bo_50_iterations_s`` (median seconds of one 50-iteration run), ``prm_build_s`` (300
milestones), ``bound_eval_ms_per_trajectory`` (eq. 9 + eq. 10 of the nominal trajectory),
``nominal_bound``, ``optimised_bound`` (median), plus the CPU. Model: the shipped ``paper``
model. ``quick``: 40 milestones, 2 seeds x 2 iterations (a smoke test, not the figures;
``bo_50_iterations_s`` is then ``None`` and ``bo_run_s`` times the 2-iteration run).

``new_robot_end_to_end_s`` (issue 19): the Kuntz lab's collapse problem (``task-0001.toml``,
the repository's copy in ``tests/data/kuntz-lab/``, or the folder in ``RISKPLAN_LAB_DATA``)
from an empty model cache to the written plan, what ``riskplan plan robot --problem
task-0001.toml`` does: the ``small`` preset's data set, training and evaluation, then the
planner's defaults (300 milestones, 50 BO iterations) and the files;
``new_robot_end_to_end_stages_s`` the seconds per stage. ``quick``: the ``tiny`` preset, 15
milestones, 1 iteration. ``None`` with ``new_robot_end_to_end_skipped`` (the reason) when the
task file is absent.
"""

from __future__ import annotations

import os
import time

import numpy as np

from riskplan.bench import cpu_model, median_time
from riskplan.threads import one_torch_thread


def lab_task():
    """The lab's collapse task file: ``$RISKPLAN_LAB_DATA/task-0001.toml`` or the repository's
    copy; ``None`` when absent (an installed package without the repository)."""
    from pathlib import Path

    env = os.environ.get("RISKPLAN_LAB_DATA")
    root = (
        Path(env) if env else Path(__file__).resolve().parents[3] / "tests" / "data" / "kuntz-lab"
    )
    task = root / "task-0001.toml"
    return task if task.is_file() else None


def new_robot_end_to_end(quick: bool = False) -> dict:
    """``plan robot`` on the lab's task from an empty cache (module docs); seconds per stage."""
    import tempfile

    from riskplan.app.outputs.robot_plan import write_robot_plan
    from riskplan.kinematics.model_cache import ensure_model
    from riskplan.planning.bo import OptimiserConfig
    from riskplan.planning.problem import load_problem
    from riskplan.planning.problem_scene import problem_configurations, problem_environment
    from riskplan.planning.robot_plan import plan_robot

    task = lab_task()
    if task is None:
        return {
            "new_robot_end_to_end_s": None,
            "new_robot_end_to_end_skipped": "the lab's task-0001.toml is absent (set RISKPLAN_LAB_DATA)",
        }
    stages = {}
    t0 = time.perf_counter()
    prob = load_problem(task)
    env = problem_environment(prob)
    start, goal = problem_configurations(prob)
    stages["inputs_s"] = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        build = ensure_model(prob.robot, preset="tiny" if quick else "small", cache=tmp)
        stages.update(build.timings)
        plan = plan_robot(
            build.model,
            env,
            start=start,
            goal=goal,
            box=build.box,
            n_milestones=15 if quick else 300,
            optimiser=OptimiserConfig(iterations=1 if quick else 50),
            seed=0,
        )
        stages.update(plan.timings)
        t = time.perf_counter()
        write_robot_plan(
            f"{tmp}/plan", plan, model=build.model, environment=env, problem=prob, build=build
        )
        stages["write_s"] = time.perf_counter() - t
    total = time.perf_counter() - t0
    return {
        "new_robot_end_to_end_s": float(total),
        "new_robot_end_to_end_stages_s": {k: float(v) for k, v in stages.items()},
        "new_robot_preset": build.record["protocol"]["name"],
        "new_robot_bounds": [float(plan.nominal_bound), float(plan.optimised.bound)],
    }


@one_torch_thread
def run(quick: bool = False, model: str = "paper") -> dict:

    from riskplan.app.reproduce.optimiser_comparison import (
        compare_optimisers,
        nominal_problem,
    )
    from riskplan.planning.risk import trajectory_risk

    milestones = 40 if quick else 300
    seeds = range(2) if quick else range(5)
    iterations = 2 if quick else 50
    t0 = time.perf_counter()
    problem = nominal_problem(model, n_milestones=milestones)
    setup_s = time.perf_counter() - t0
    nominal = problem["nominal"]
    eval_ms = (
        median_time(
            lambda: trajectory_risk(problem["bound"], nominal), repeats=3 if quick else 10, warmup=1
        )
        * 1e3
    )
    # serial: the per-run time is what a user waits for one optimisation
    rows = compare_optimisers(
        problem, methods=("bo",), seeds=seeds, iterations=iterations, backend="serial"
    )
    return {
        **new_robot_end_to_end(quick),
        "bound_reduction": float(np.median([r["reduction"] for r in rows])),
        "bo_50_iterations_s": None if quick else float(np.median([r["seconds"] for r in rows])),
        "bo_run_s": float(np.median([r["seconds"] for r in rows])),
        "prm_build_s": float(problem["roadmap"].build_seconds),
        "prm_milestones": int(milestones),
        "bound_eval_ms_per_trajectory": float(eval_ms),
        "trajectory_configurations": len(nominal),
        "nominal_bound": float(rows[0]["initial_bound"]),
        "optimised_bound": float(np.median([r["bound"] for r in rows])),
        "optimised_bound_range": [
            float(min(r["bound"] for r in rows)),
            float(max(r["bound"] for r in rows)),
        ],
        "seeds": len(rows),
        "iterations": iterations,
        "setup_s": float(setup_s),
        "cpu_model": cpu_model(),
        "cpu_cores": os.cpu_count(),
    }
