"""Planning under uncertainty in deformable tissue, end to end (Patil, van den Berg &
Alterovitz, RSS 2011, Fig. 2): simulator RRT candidates → linearisation, LQG and LQG-MP
selection → the LQG-MP estimate checked against closed-loop executions; figures of the
candidates with the chosen plan (paper Figs. 1b/1d, 7b) and an animation of one execution.

Used by ``riskplan plan tissue``, ``riskplan bench planning-tissue`` and the demo stage
``planning_tissue``. Matplotlib is imported inside the plotting functions only.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from riskplan.errors import InvalidInputError

log = logging.getLogger(__name__)

__all__ = [
    "SELECTIONS",
    "TissuePlanningResult",
    "candidates_figure",
    "execution_gif",
    "plan_tissue",
    "selection_setup",
    "write_outputs",
]


#: How ``plan tissue`` selects (``selection=``): ``"paper"`` is the paper's σ-distance on
#: the world-frame LQG; ``"calibrated"`` (the default outside the paper reproduction) is,
#: per scenario, the estimator and controller whose predicted P(success) matched measured
#: closed-loop success best in the calibration study (docs/control.md, "Calibration";
#: ``frame``: the needle's reduced-state frame, :meth:`NeedleScenario.with_frame`).
SELECTIONS = {
    "paper": {
        "needle": {"frame": None, "method": "sigma", "disturbance": False},
        "manipulation": {"frame": None, "method": "sigma", "disturbance": False},
    },
    "calibrated": {
        "needle": {"frame": "material", "method": "sampling", "disturbance": True},
        "manipulation": {"frame": None, "method": "sampling", "disturbance": True},
    },
}


def selection_setup(sim, plans, selection: str):
    """``(sim, plans, method, disturbance)`` of a :data:`SELECTIONS` entry for ``sim``
    (``sim.name``; a scenario file's kind): the simulator and plans in the entry's frame
    (:meth:`~riskplan.control.NominalPlan.reframed`), its LQG-MP method and controller."""
    if selection not in SELECTIONS:
        raise InvalidInputError(
            f"selection: expected one of {', '.join(SELECTIONS)}, got {selection!r}"
        )
    entry = SELECTIONS[selection].get(getattr(sim, "name", ""), SELECTIONS["paper"]["needle"])
    if entry["frame"] is not None and callable(getattr(sim, "with_frame", None)):
        sim = sim.with_frame(entry["frame"])
        plans = [p.reframed(sim) for p in plans]
    return sim, plans, entry["method"], entry["disturbance"]


@dataclass
class TissuePlanningResult:
    """Everything one run produces: the scenario (``sim``, with the case's distribution),
    ``plans``, ``trees``, the :class:`~riskplan.planning.select.Selection`, the honesty rows
    and wall-clock ``timings`` (seconds: ``rrt``, ``selection``, ``check``);
    ``selection_mode`` (:data:`SELECTIONS`) and ``frame`` (the needle's reduced-state frame
    of the selection; ``selection.plan`` and its controller are in it)."""

    scenario: str
    case: str
    seed: int
    sim: object
    plans: list
    trees: list
    selection: object
    honesty: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    selection_mode: str = "paper"
    frame: str | None = None


def plan_tissue(
    scenario: str = "needle",
    *,
    n_plans: int = 100,
    case: str = "material-high",
    seed: int = 0,
    workers: int | None = None,
    backend: str = "local",
    rrt_options=None,
    method: str | None = None,
    n_samples: int = 16,
    check_runs: int = 1000,
    check_others: int = 2,
    on_tree=None,
    on_plan=None,
    on_check=None,
    selection: str = "calibrated",
) -> TissuePlanningResult:
    """Run the method on one scenario (``"needle"`` or ``"manipulation"``) and uncertainty
    ``case`` (:data:`riskplan.scenarios.uncertainty.CASE_NAMES`).

    ``n_plans`` candidates from :func:`~riskplan.planning.rrt.rrt_plans`, selection by
    :func:`~riskplan.planning.select.select_plan` (``method``, ``n_samples`` parameter draws
    per step for ``M_t``), then ``check_runs`` closed-loop executions for the selected plan
    and ``check_others`` more (``check_runs = 0`` skips the check). ``on_tree(i, tree)``,
    ``on_plan(i, score)``, ``on_check(row)`` report progress. ``selection``: ``"calibrated"``
    (default) or ``"paper"`` (:data:`SELECTIONS`); ``method`` overrides its LQG-MP method.
    """
    from riskplan._validation import check_count
    from riskplan.control.lqgmp import METHODS
    from riskplan.planning.rrt import RRTOptions, rrt_plans
    from riskplan.planning.select import honesty_check, select_plan
    from riskplan.scenarios.registry import make_scenario

    # every argument checked before the trees grow (a bad method used to fail after them)
    if method is not None and method not in METHODS:
        raise InvalidInputError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    if selection not in SELECTIONS:
        raise InvalidInputError(
            f"selection: expected one of {', '.join(SELECTIONS)}, got {selection!r}"
        )
    n_plans = check_count(n_plans, "n_plans", 1)
    check_runs = check_count(check_runs, "check_runs", 0)
    check_others = check_count(check_others, "check_others", 0)
    sim = make_scenario(scenario, case)
    check_tissue_budget(sim, n_plans=n_plans, check_runs=check_runs, check_others=check_others)
    options = rrt_options or RRTOptions()
    timings = {}
    t0 = time.perf_counter()
    plans, trees = rrt_plans(
        sim, n_plans, seed=seed, options=options, backend=backend, workers=workers, on_tree=on_tree
    )
    timings["rrt"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ssim, splans, smethod, dist = selection_setup(sim, plans, selection)
    mode = selection
    selection = select_plan(
        ssim,
        splans,
        sim.distribution,
        method=smethod if method is None else method,
        disturbance=dist,
        n_samples=n_samples,
        seed=seed + 1,
        backend=backend,
        workers=workers,
        on_result=on_plan,
    )
    timings["selection"] = time.perf_counter() - t0
    rows = []
    if check_runs:
        t0 = time.perf_counter()
        rows = honesty_check(
            ssim,
            splans,
            selection,
            sim.distribution,
            others=check_others,
            n=check_runs,
            seed=seed + 2,
            backend=backend,
            workers=workers,
            on_row=on_check,
        )
        timings["check"] = time.perf_counter() - t0
    return TissuePlanningResult(
        scenario,
        case,
        seed,
        sim,
        plans,
        trees,
        selection,
        rows,
        timings,
        selection_mode=mode,
        frame=getattr(ssim, "frame", None) if ssim is not sim else None,
    )


#: least time of one simulator step (s): a tenth of the measured 16.5 µs of a needle step on
#: the 175-element mesh (README, `riskplan tissue step-cost`, 2-core AMD EPYC, shared); the
#: manipulation step is 50 times slower
STEP_S = 1.65e-6


def check_tissue_budget(sim, *, n_plans: int, check_runs: int, check_others: int) -> None:
    """Refuse a run whose work exceeds the budget (:mod:`riskplan.budget`) before any work:
    the candidates (``--plans``: each keeps at least two simulator states, the mesh
    displacement at 2 float64 per node) and the Monte Carlo check (``--check-runs``
    executions of each checked plan, each at least one simulator step)."""
    from riskplan.budget import check_budget

    nodes = sim.mesh_data(sim.nominal_params.n_elements).mesh.n_nodes
    check_budget(
        f"{n_plans} candidate plans", "--plans", nbytes=float(n_plans) * 2 * 2 * 8.0 * nodes
    )
    n_checked = min(n_plans, 1 + check_others)
    check_budget(
        f"{check_runs} closed-loop executions of {n_checked} plans",
        "--check-runs",
        seconds=float(check_runs) * n_checked * STEP_S,
    )


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
      honesty check (ranks 1-based, 1 = selected, as in the table), timings;
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
            "honesty_check": [dict(asdict(r), inside=r.inside) for r in result.honesty],
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
    """Table rows for the honesty check: candidate, rank, LQG-MP, Monte Carlo, interval."""
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
        for r in result.honesty
    ]


HONESTY_HEADER = [
    "candidate",
    "rank",
    "P(success) LQG-MP",
    "success rate (MC)",
    "95 % interval",
    "runs",
    "inside",
]
