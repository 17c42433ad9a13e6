"""What ``riskplan plan tissue`` writes for a :func:`riskplan.tissue_planning.plan.plan_tissue`
run: figures of the candidates with the chosen plan (paper Figs. 1b/1d, 7b), an animation of
one execution, the plans and tables.

Used by ``riskplan plan tissue``, ``riskplan bench planning-tissue`` and the demo stage
``planning_tissue``. Matplotlib is imported inside the plotting functions only.
"""

from __future__ import annotations

import logging
from dataclasses import asdict
from pathlib import Path

import numpy as np

from riskplan.tissue_planning.plan import TissuePlanningResult

log = logging.getLogger(__name__)

__all__ = ["candidates_figure", "execution_gif", "summary_rows", "write_outputs"]


# ---- figures ----------------------------------------------------------------------------


def candidates_figure(sim, plans, best: int, *, title: str | None = None, size: float = 5.2):
    """The candidates (thin grey: robot path for the needle, target path for the
    manipulation scenario) over the scene at the end of the chosen plan, the chosen one
    highlighted (paper Figs. 1b/1d, 7b). Returns the matplotlib figure."""
    import matplotlib.pyplot as plt

    from riskplan.scenarios.plotting import draw_frame

    fig, ax = plt.subplots(figsize=(size, size))
    chosen = plans[best]
    draw_frame(
        ax,
        sim,
        list(chosen.states),
        title=title or f"{sim.name}: {len(plans)} candidates, chosen #{best}",
    )
    for i, plan in enumerate(plans):
        if i == best:
            continue
        path = sim.path(plan.states)
        ax.plot(path[:, 0], path[:, 1], "-", color="0.25", lw=0.6, alpha=0.45, zorder=1)
    path = sim.path(chosen.states)
    ax.plot(
        path[:, 0], path[:, 1], "-", color="tab:orange", lw=2.5, zorder=5, label="selected (LQG-MP)"
    )
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    return fig


def execution_gif(
    sim, plan, controller, params, path, *, seed=0, max_frames: int = 40
) -> tuple[Path, object]:
    """Animated GIF of one closed-loop LQG execution of ``plan`` under ``params`` (one draw
    of the case); returns the path and the :class:`~riskplan.control.lqg.Execution`."""
    from riskplan.control.lqg import execute
    from riskplan.scenarios.plotting import save_gif

    ex = execute(sim, plan, controller, params, seed=seed)
    return save_gif(sim, list(ex.states), path, max_frames=max_frames), ex


# ---- files ------------------------------------------------------------------------------


def _pack(plans) -> dict:
    """Variable-length plans as flat arrays plus offsets: plan ``i`` has controls
    ``controls[c_off[i]:c_off[i+1]]`` and reduced states ``reduced[x_off[i]:x_off[i+1]]``."""
    c_off = np.cumsum([0] + [p.n_steps for p in plans])
    x_off = np.cumsum([0] + [p.n_steps + 1 for p in plans])
    return {
        "controls": np.concatenate([p.controls for p in plans]),
        "reduced": np.concatenate([p.reduced for p in plans]),
        "control_offsets": c_off,
        "state_offsets": x_off,
    }


def _savez_atomic(path: Path, **arrays) -> None:
    from riskplan.io import atomic_path

    with atomic_path(path, suffix=".npz") as tmp:
        np.savez_compressed(tmp, **arrays)


def write_outputs(
    result: TissuePlanningResult, out, *, gif: bool = True, gif_seed: int = 0
) -> dict:
    """Write the run into folder ``out`` (atomic writes) and return ``{name: path}``:

    * ``candidates.npz`` (:func:`_pack` layout) and ``candidates.json`` (LQG-MP scores);
    * ``selected.npz``: the chosen plan's ``controls (T, q)``, ``reduced (T+1, p)`` and gains
      ``L (T, q, p)``, ``K (T, p, m)``, ``P (T, p, p)``, ``A``, ``B``, ``M``, ``H``, ``N``;
    * ``selected_controls.csv`` and ``selected_gains.npz``: the controller's files
      (:func:`riskplan.planning.export.write_tissue_plan`);
    * ``selected.json``: scenario, case, seed, index (0-based candidate), probabilities, the
      calibration check (key ``calibration_check``; ranks 1-based, 1 = selected, as in the table), timings;
    * ``candidates.png`` and ``execution.gif`` (one closed-loop run under a draw of the case).
    """
    from riskplan.io import write_json_atomic

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sel = result.selection
    sim = result.sim
    files = {}
    files["candidates.npz"] = out / "candidates.npz"
    _savez_atomic(files["candidates.npz"], **_pack(result.plans))
    files["candidates.json"] = out / "candidates.json"
    write_json_atomic(
        files["candidates.json"],
        {
            "scenario": result.scenario,
            "case": result.case,
            "seed": result.seed,
            "method": sel.method,
            "scores": [asdict(s) for s in sorted(sel.ranking, key=lambda s: s.index)],
            "trees": [
                {
                    "seed": t.seed,
                    "nodes": t.size,
                    "iterations": t.iterations,
                    "plans": len(t.plans),
                    "best_goal_distance": t.best_goal_distance,
                }
                for t in result.trees
            ],
        },
    )
    c = sel.controller
    files["selected.npz"] = out / "selected.npz"
    _savez_atomic(
        files["selected.npz"],
        controls=sel.plan.controls,
        reduced=sel.plan.reduced,
        L=c.L,
        K=c.K,
        P=c.P,
        A=c.lin.A,
        B=c.lin.B,
        M=c.lin.M,
        H=c.lin.H,
        N=c.lin.N,
    )
    from riskplan.planning.export import write_tissue_plan

    # the needle steps by tau seconds; the manipulation scenario is quasi-static (no duration)
    dt = getattr(getattr(sim, "config", None), "tau", None)
    free = getattr(sel.result, "p_free_steps", None)
    risk = None if free is None else 1.0 - np.asarray(free, dtype=np.float64)
    exported = write_tissue_plan(out, sel.plan, c, dt=dt, risk=risk, stem="selected")
    files["selected_controls.csv"] = exported["controls"]
    files["selected_gains.npz"] = exported["gains"]
    best = sel.score(sel.best)
    files["selected.json"] = out / "selected.json"
    write_json_atomic(
        files["selected.json"],
        {
            "scenario": result.scenario,
            "case": result.case,
            "seed": result.seed,
            "index": sel.best,
            "n_steps": sel.plan.n_steps,
            "p_success": best.p_success,
            "p_collision_free": best.p_collision_free,
            "p_goal": best.p_goal,
            "method": sel.method,
            "selection": result.selection_mode,
            "frame": result.frame,
            "n_tied": sel.n_tied,
            "tie": sel.tie_note,
            "calibration_check": [
                dict(asdict(r), inside=r.inside) for r in result.calibration_rows
            ],
            "timings_s": result.timings,
            "n_candidates": len(result.plans),
        },
    )
    import matplotlib.pyplot as plt

    fig = candidates_figure(sim, result.plans, sel.best)
    files["candidates.png"] = out / "candidates.png"
    from riskplan.io import atomic_path

    with atomic_path(files["candidates.png"], suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    if gif:
        params = sim.sample_params(gif_seed)
        files["execution.gif"], _ = execution_gif(
            sim, sel.plan, sel.controller, params, out / "execution.gif", seed=gif_seed
        )
    return files


def summary_rows(result: TissuePlanningResult) -> list[list]:
    """Table rows for the calibration check: candidate, rank, LQG-MP, Monte Carlo, interval."""
    return [
        [
            r.index,
            r.rank,
            r.p_lqgmp,
            r.p_mc,
            f"[{r.low:.3f}, {r.high:.3f}]",
            r.n,
            "yes" if r.inside else "no",
        ]
        for r in result.calibration_rows
    ]


CALIBRATION_HEADER = [
    "candidate",
    "rank",
    "P(success) LQG-MP",
    "success rate (MC)",
    "95 % interval",
    "runs",
    "inside",
]
