"""Optimiser comparison on the chest nominal trajectory (beyond the MDN paper, issue part 5).

One nominal trajectory (PRM, ``roadmap_seed``), then for every method and optimiser seed the
same budget of eq.-9 evaluations (one per iteration):

* ``random`` — random local search: the BO's candidates, one picked at random, no GP;
* ``bo`` — the paper's Bayesian optimisation (``riskplan.planning.bo``);
* ``trust_region`` — the same GP/acquisition in a TuRBO-style adaptive trust region, moving
  the riskiest configuration.

:func:`compare_optimisers` returns one row per (method, seed) and :func:`summarise` the median
and spread (min-max and interquartile range) per method. Run from the command line::

    python -m riskplan.app.reproduce.optimiser_comparison --iterations 50 --seeds 5 --out DIR
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from riskplan.threads import one_torch_thread

METHODS = ("random", "bo", "trust_region")


def nominal_problem(
    model="paper",
    *,
    chest_seed: int = 0,
    roadmap_seed: int = 0,
    goal_tip=None,
    n_milestones: int = 300,
):
    """``(model, environment (base frame), validity, bound, nominal (T, m), bounds (T,))`` of the default scene."""
    from riskplan.kinematics import load_model
    from riskplan.planning.chest import DEFAULT_GOAL
    from riskplan.planning.chest_scene import build_chest
    from riskplan.planning.prm import (
        MeanValidity,
        build_roadmap,
        goal_from_tip,
        interpolate_path,
    )
    from riskplan.planning.risk import ConfigurationBound, trajectory_risk

    mdl = load_model(model) if isinstance(model, (str, Path)) else model
    env = build_chest(chest_seed).base_environment
    validity = MeanValidity(mdl, env)
    rm = build_roadmap(validity, n_milestones=n_milestones, seed=roadmap_seed)
    start = np.clip(np.zeros(mdl.n_tendons), mdl.limits[:, 0], mdl.limits[:, 1])
    goal = (
        np.asarray(DEFAULT_GOAL, dtype=np.float64)
        if goal_tip is None
        else goal_from_tip(rm, mdl, goal_tip, seed=roadmap_seed)
    )
    nominal = interpolate_path(rm.shortest_path(start, goal))
    bound = ConfigurationBound(mdl, env)
    _, p = trajectory_risk(bound, nominal)
    return {
        "model": mdl,
        "environment": env,
        "validity": validity,
        "bound": bound,
        "nominal": nominal,
        "bounds": p,
        "roadmap": rm,
    }


@one_torch_thread
def _run_one(args):

    from riskplan.planning.bo import OptimiserConfig, optimise_trajectory

    problem, method, seed, iterations = args
    cfg = OptimiserConfig(iterations=iterations, method=method)
    t0 = time.perf_counter()
    res = optimise_trajectory(
        problem["nominal"],
        problem["bound"],
        problem["validity"],
        problem["model"].limits,
        config=cfg,
        seed=seed,
        bounds=problem["bounds"],
    )
    return {
        "method": method,
        "seed": seed,
        "initial_bound": res.initial_bound,
        "bound": res.bound,
        "reduction": res.reduction,
        "evaluations": res.evaluations,
        "seconds": time.perf_counter() - t0,
        "trace": res.trace.tolist(),
    }


def compare_optimisers(
    problem: dict,
    *,
    methods=METHODS,
    seeds=(0, 1, 2, 3, 4),
    iterations: int = 50,
    workers: int | None = None,
    backend: str = "local",
    on_result=None,
) -> list[dict]:
    """One row per (method, seed): final eq.-10 bound, reduction, evaluations, seconds, trace."""
    from riskplan.parallel import map_tasks

    light = {k: v for k, v in problem.items() if k != "roadmap"}  # what the workers need
    tasks = [(light, m, int(s), int(iterations)) for m in methods for s in seeds]
    return map_tasks(
        _run_one, tasks, backend=backend, workers=workers, chunksize=1, on_result=on_result
    )


def summarise(rows: list[dict]) -> list[dict]:
    """Median, quartiles and range of the final bound and reduction per method."""
    out = []
    for m in dict.fromkeys(r["method"] for r in rows):
        b = np.array([r["bound"] for r in rows if r["method"] == m])
        red = np.array([r["reduction"] for r in rows if r["method"] == m])
        out.append(
            {
                "method": m,
                "runs": len(b),
                "median_bound": float(np.median(b)),
                "bound_q25": float(np.quantile(b, 0.25)),
                "bound_q75": float(np.quantile(b, 0.75)),
                "min_bound": float(b.min()),
                "max_bound": float(b.max()),
                "median_reduction": float(np.median(red)),
                "min_reduction": float(red.min()),
                "max_reduction": float(red.max()),
                "evaluations": int(np.median([r["evaluations"] for r in rows if r["method"] == m])),
                "median_seconds": float(
                    np.median([r["seconds"] for r in rows if r["method"] == m])
                ),
            }
        )
    return out


def to_markdown(summary: list[dict], initial_bound: float) -> str:
    lines = [
        f"Nominal eq.-10 bound: {initial_bound:.4f}",
        "",
        "| method | runs | bound evaluations | median bound | IQR | range | median reduction | median s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        lines.append(
            f"| {s['method']} | {s['runs']} | {s['evaluations']} | {s['median_bound']:.4f} | "
            f"{s['bound_q25']:.4f}-{s['bound_q75']:.4f} | {s['min_bound']:.4f}-{s['max_bound']:.4f} | "
            f"{100 * s['median_reduction']:.1f} % | {s['median_seconds']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def trace_table(rows: list[dict], at=(5, 10, 20, 30, 50)) -> str:
    """Markdown: median [min-max] of the best eq.-10 bound after the given iterations, per method."""
    its = [k for k in at if k < len(rows[0]["trace"])]
    lines = [
        "| method | " + " | ".join(f"after {k}" for k in its) + " |",
        "|---|" + "---|" * len(its),
    ]
    for m in dict.fromkeys(r["method"] for r in rows):
        tr = np.array([r["trace"] for r in rows if r["method"] == m])
        cells = [
            f"{100 * np.median(tr[:, k]):.2f} % [{100 * tr[:, k].min():.2f}-{100 * tr[:, k].max():.2f}]"
            for k in its
        ]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def traces_figure(rows: list[dict]):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    colours = {"random": "gray", "bo": "royalblue", "trust_region": "darkorange"}
    for m in dict.fromkeys(r["method"] for r in rows):
        tr = np.array([r["trace"] for r in rows if r["method"] == m])
        it = np.arange(tr.shape[1])
        ax.plot(it, 100 * np.median(tr, 0), color=colours.get(m), label=f"{m} (median)")
        ax.fill_between(it, 100 * tr.min(0), 100 * tr.max(0), color=colours.get(m), alpha=0.15)
    ax.set_xlabel("iteration (= eq.-9 evaluations)")
    ax.set_ylabel("eq.-10 bound [%]")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return fig


def run_comparison(
    out, *, model: str = "paper", iterations: int = 50, seeds: int = 5, workers: int | None = None
) -> str:
    """The comparison of ``riskplan study optimisers``: ``seeds`` runs of each optimiser for
    ``iterations`` iterations on the nominal chest problem of ``model``; writes
    ``out/comparison.json``, ``.md`` and ``.png`` (atomic writes) and returns the Markdown."""
    from riskplan.io import atomic_path, write_json_atomic, write_text_atomic

    out = Path(out)
    problem = nominal_problem(model)
    rows = compare_optimisers(problem, seeds=range(seeds), iterations=iterations, workers=workers)
    summary = summarise(rows)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(
        out / "comparison.json",
        {"rows": rows, "summary": summary, "nominal_bound": rows[0]["initial_bound"]},
    )
    p = problem["bounds"]
    floor = float(1 - (1 - p[0]) * (1 - p[-1]))  # start and goal never move
    md = (
        to_markdown(summary, rows[0]["initial_bound"])
        + f"\nFloor (start and goal fixed): {floor:.4f}\n\n"
        + trace_table(rows)
    )
    write_text_atomic(out / "comparison.md", md)
    import matplotlib

    matplotlib.use("Agg")
    fig = traces_figure(rows)
    with atomic_path(out / "comparison.png", suffix=".png") as tmp:
        fig.savefig(tmp, dpi=120)
    return md
