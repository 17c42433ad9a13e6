"""``riskplan bench planning``: the chest-cavity planner (MDN paper section V, Fig. 7).

Keys (issue 10): ``bound_reduction`` (relative reduction of the eq.-10 bound after 50 BO
iterations, median over 5 optimiser seeds on the default scene's nominal trajectory),
``bo_50_iterations_s`` (median seconds of one 50-iteration run), ``prm_build_s`` (300
milestones), ``bound_eval_ms_per_trajectory`` (eq. 9 + eq. 10 of the nominal trajectory),
``nominal_bound``, ``optimised_bound`` (median), plus the CPU. Model: the shipped ``paper``
model. ``quick``: 40 milestones, 2 seeds x 2 iterations (a smoke test, not the figures;
``bo_50_iterations_s`` is then ``None`` and ``bo_run_s`` times the 2-iteration run).
"""

from __future__ import annotations

import os
import time

import numpy as np

from riskplan.bench import cpu_model, median_time


def run(quick: bool = False, model: str = "paper") -> dict:
    import torch

    from riskplan.experiments.optimiser_comparison import (
        compare_optimisers,
        nominal_problem,
    )
    from riskplan.planning.risk import trajectory_risk

    torch.set_num_threads(1)
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
