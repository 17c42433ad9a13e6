"""The 3-D needle's reproduction stage and outputs: the interactive plotly figure
(:func:`needle3d_figure`), the files of ``riskplan plan needle3d`` (:func:`write_outputs`) and
the ``reproduce`` stage ``needle3d`` (:func:`run_needle3d` at the sizes of
:data:`NEEDLE3D_SCALES`). The planning itself — simulator RRT candidates, LQG-MP selection in
3-D and the check against closed- and open-loop executions — is the library's
:func:`riskplan.tissue_planning.plan_needle3d`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from riskplan.tissue_planning.needle3d import Needle3DResult, plan_needle3d

__all__ = [
    "NEEDLE3D_SCALES",
    "SUMMARY_HEADER",
    "needle3d_figure",
    "run_needle3d",
    "summary_rows",
    "write_outputs",
]

#: the columns of :func:`summary_rows` (the table ``riskplan plan needle3d`` prints)
SUMMARY_HEADER = (
    "plan",
    "steps",
    "trunc",
    "per-step",
    "sigma",
    "sampling",
    "particles",
    "closed",
    "95% CI",
    "trunc ±2pt",
    "first",
    "open",
)


def summary_rows(result: Needle3DResult) -> list[tuple[str, ...]]:
    """One row of strings per candidate, in the ranking's order, under :data:`SUMMARY_HEADER`:
    index, steps, the LQG-MP estimates (truncation, per-step, sigma, sampling, particles),
    the closed-loop successes and their 95 % Wilson interval, whether the truncation lies
    within ±2 points of them, and the closed and open loop on the first draws ("-" where a
    candidate was not checked or a value does not apply)."""
    rows = []
    for r in result.rows:
        e = r.estimates
        near = r.checks.get("truncation", {}).get("within_points")
        particles = e.get("particles", math.nan)
        rows.append(
            (
                str(r.index),
                str(r.n_steps),
                *(f"{e[m]:.3f}" for m in ("truncation", "per-step", "sigma", "sampling")),
                "-" if math.isnan(particles) else f"{particles:.3f}",
                f"{r.closed}/{r.n}" if r.n else "-",
                f"[{r.closed_ci[0]:.3f}, {r.closed_ci[1]:.3f}]" if r.n else "-",
                "-" if near is None else ("yes" if near else "no"),
                f"{r.closed_first}/{r.n_open}" if r.n else "-",
                f"{r.open}/{r.n_open}" if r.n else "-",
            )
        )
    return rows


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
    """The ``reproduce`` stage ``needle3d``: :func:`~riskplan.tissue_planning.plan_needle3d` at the sizes of
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
