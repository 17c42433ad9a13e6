"""The MDN paper's results for ``riskplan reproduce`` (Thompson, Cho, Brown & Kuntz): Fig. 4
(test NLL against the number of mixture components K), Fig. 5 (samples of the predicted
mixture against ground-truth points) and the MDN-vs-Cosserat timing of §V, computed with
the library's own data-set generator (simulated robot and cameras), trainer and sweep.

Fig. 7 (:func:`run_fig7`): the chest planner (:func:`riskplan.planning.chest.plan_chest`, the
same as ``riskplan plan chest`` with its defaults) with the shipped model
(``load_model("paper")``) in the procedural chest: the PRM's nominal trajectory, its eq.-10
bound, ``MDNScale.bo_iterations`` iterations of Bayesian optimisation (paper: 50), and the
paper's "about 15 % before, below 7 % after 50 iterations" checked from the numbers
(:func:`fig7_claims`); beside it, both trajectories executed ``MDNScale.robot_executions``
times on the simulated robot (:func:`riskplan.planning.validate.validation_table`, the same
executions for both: common random numbers), so the report shows what the bound's drop does on
the robot.

Numbers that depend on wall-clock time (training budgets, timings) are stored once in the
:class:`~riskplan.app.store.ResultStore` when computed, so a rerun reports the
same values.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from riskplan._validation import check_count, check_count_list
from riskplan.app.demo.kinematics import TRAIN
from riskplan.errors import InvalidInputError
from riskplan.threads import one_torch_thread

log = logging.getLogger(__name__)

__all__ = ["MDN_SCALES", "MDNScale", "fig7_claims", "run_fig7", "run_mdn"]


@dataclass(frozen=True)
class MDNScale:
    """Sizes of the MDN part. ``preset``: data-set protocol (:data:`riskplan.datasets.PRESETS`);
    ``components``: the K of Fig. 4; ``n_components``: K of the Fig. 5 model; ``epochs`` /
    ``sweep_epochs``: at most this many epochs; ``train_seconds`` / ``sweep_seconds``:
    wall-clock budgets (``0`` = none); ``timing_configs``: random configurations timed;
    ``bo_iterations`` / ``bo_candidates`` / ``milestones``: Fig. 7's Bayesian optimisation
    iterations (paper: 50), candidates per iteration and PRM milestones; ``robot_executions``:
    executions of each Fig. 7 trajectory on the simulated robot (``0``: none)."""

    preset: str = "small"
    components: tuple = (1, 2, 3, 5)
    n_components: int = 5
    epochs: int = 400
    sweep_epochs: int = 150
    train_seconds: float = 20.0
    sweep_seconds: float = 5.0
    timing_configs: int = 200
    bo_iterations: int = 10
    bo_candidates: int = 256
    milestones: int = 300
    robot_executions: int = 200

    def __post_init__(self):
        object.__setattr__(self, "components", check_count_list(self.components, "components"))
        for name in ("bo_iterations", "bo_candidates", "milestones", "robot_executions"):
            low = 0 if name in ("bo_iterations", "robot_executions") else 1
            check_count(getattr(self, name), name, low, integral=True)


MDN_SCALES = {
    "smoke": MDNScale(),
    "paper": MDNScale(
        preset="paper",
        components=tuple(range(1, 11)),
        epochs=2000,
        sweep_epochs=2000,
        train_seconds=0.0,
        sweep_seconds=0.0,
        timing_configs=10_000,
        bo_iterations=50,
        robot_executions=1000,
    ),
}


def _timing(model, robot, n: int, seed: int) -> dict:
    """Mean time of one ``model.predict`` and one Cosserat solve (``robot.solve_displacements``)
    over ``n`` random realisable configurations (MDN paper §V: 10,000 configurations)."""
    limits = np.asarray(robot.displacement_limits, dtype=np.float64)
    rng = np.random.default_rng(seed)
    cand = rng.uniform(limits[:, 0], limits[:, 1], size=(4 * n, limits.shape[0]))
    ok = (robot.tensions_for_displacements(cand) <= robot.tension_limits).all(-1)
    cfgs = cand[ok][:n] if ok.sum() >= 1 else cand[:n]
    for q in cfgs[:5]:
        model.predict(q)
    t0 = time.perf_counter()
    for q in cfgs:
        model.predict(q)
    mdn = (time.perf_counter() - t0) / len(cfgs)
    m = min(len(cfgs), max(10, n // 10))
    for q in cfgs[:2]:  # compile the solver's kernels outside the timed loop
        robot.solve_displacements(q)
    t0 = time.perf_counter()
    for q in cfgs[:m]:
        robot.solve_displacements(q)
    cos = (time.perf_counter() - t0) / m
    return {
        "mdn_ms": mdn * 1e3,
        "cosserat_ms": cos * 1e3,
        "configs": len(cfgs),
        "cosserat_configs": int(m),
        "reduction_percent": 100.0 * (1.0 - mdn / cos),
    }


@one_torch_thread
def run_mdn(
    out,
    scale: MDNScale,
    store,
    *,
    seed: int = 0,
    workers: int | None = None,
    backend: str = "local",
    ray_address: str | None = None,
    progress=None,
) -> dict:
    """Figs. 4-5 and the timing of the MDN paper into ``out`` (PNG + plotly pages written
    when first computed). Returns the JSON numbers (also stored under ``mdn.results``).
    ``workers``, ``backend``, ``ray_address``: the data sets' and the K sweep's task maps
    (inside ``reproduce``'s :class:`~riskplan.parallel.TaskPool` they run on its workers)."""
    found = store.get("mdn.results")
    if found is not None:
        return found

    from riskplan.datasets import generate_splits
    from riskplan.kinematics.data import read_point_clouds
    from riskplan.kinematics.evaluation import evaluate_for_report
    from riskplan.robots import load_robot

    report = progress or (lambda stage, done, total: None)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    steps = 4
    report("mdn: data set", 0, steps)
    robot = load_robot("paper")
    paths = generate_splits(
        robot,
        scale.preset,
        out / "data" / scale.preset,
        seed=seed,
        workers=workers,
        backend=backend,
        ray_address=ray_address,
    )
    train_data, test_data = read_point_clouds(paths["train"]), read_point_clouds(paths["test"])
    report("mdn: train (Fig. 5)", 1, steps)
    model, n_epochs = _fig5_model(train_data, out / "model", scale, store, seed)
    ev = evaluate_for_report(model, test_data, seed)
    _fig5_figures(model, test_data, out, seed)
    report("mdn: K sweep (Fig. 4)", 2, steps)
    sw = _fig4_sweep(paths, out, scale, seed, workers, backend, ray_address)
    report("mdn: timing", 3, steps)
    timing = _timing(model, robot, scale.timing_configs, seed)
    report("mdn: timing", 4, steps)
    result = {
        "train_configs": int(train_data.n_configs),
        "test_configs": int(test_data.n_configs),
        "epochs": n_epochs,
        "test_nll": float(ev.nll),
        "chamfer_mm": float(ev.chamfer * 1e3),
        "calibration": {str(k): float(v) for k, v in ev.calibration.items()},
        "sweep": [
            {
                "k": e.n_components,
                "test_nll": (float(e.test_nll) if np.isfinite(e.test_nll) else None),
                "collapsed": list(map(int, e.collapsed)),
                "epochs": int(e.epochs),
            }
            for e in sw.entries
        ],
        "recommended_k": int(sw.recommended),
        "timing": timing,
        "figures": {"fig4": "mdn/fig4.png", "fig5": "mdn/fig5.png", "fig5_html": "mdn/fig5.html"},
    }
    store.put("mdn.results", result)
    return result


def _fig5_model(train_data, model_dir: Path, scale: MDNScale, store, seed: int):
    """``(model, epochs)``: the Fig. 5 model (``scale.n_components`` components) trained on
    ``train_data`` into ``model_dir`` within the scale's epoch and wall-clock budgets, or the
    saved model of an earlier run that finished training (record ``mdn.model``)."""
    from riskplan.kinematics import load_model
    from riskplan.kinematics.training import CHECKPOINT_NAME, TrainConfig, train

    cfg = TrainConfig(n_components=scale.n_components, epochs=scale.epochs, seed=seed, **TRAIN)
    trained = store.get("mdn.model")
    if trained is not None:  # finished in an earlier (interrupted) run: its saved model
        return load_model(model_dir), int(trained["epochs"])
    # a run killed during training left its checkpoint: continue it (a rerun of the same
    # command must finish, not ask for --resume); otherwise start afresh
    resume = (model_dir / CHECKPOINT_NAME).is_file()
    res = train(
        train_data,
        cfg,
        out=model_dir,
        resume=resume,
        overwrite=not resume,
        max_seconds=scale.train_seconds or None,
    )
    n_epochs = len(res.history)
    store.put("mdn.model", {"epochs": n_epochs, "best_epoch": int(res.best_epoch)})
    return res.model, n_epochs


def _fig5_figures(model, test_data, out: Path, seed: int) -> None:
    """Fig. 5: samples of the predicted mixture against the ground-truth points of two test
    configurations, as ``out/fig5.png`` and the plotly page ``out/fig5.html``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from riskplan.kinematics.plotting import fig_samples_vs_truth, plotly_samples_vs_truth

    fig = fig_samples_vs_truth(model, test_data, n_configs=2, n_samples=1500, seed=seed)
    fig.savefig(out / "fig5.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    plotly_samples_vs_truth(model, test_data, n_configs=2, n_samples=1500, seed=seed).write_html(
        out / "fig5.html", include_plotlyjs="directory", full_html=True
    )


def _fig4_sweep(paths: dict, out: Path, scale: MDNScale, seed: int, workers, backend, ray_address):
    """Fig. 4: the test NLL against the number of components K (``scale.components``,
    :func:`riskplan.kinematics.sweep.sweep` into ``out/sweep``), drawn as ``out/fig4.png``.
    Returns the sweep."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from riskplan.kinematics.plotting import fig_nll_vs_components
    from riskplan.kinematics.sweep import sweep
    from riskplan.kinematics.training import TrainConfig

    sw = sweep(
        paths["train"],
        paths["test"],
        list(scale.components),
        TrainConfig(epochs=scale.sweep_epochs, seed=seed, **TRAIN),
        out=out / "sweep",
        workers=workers,
        backend=backend,
        ray_address=ray_address,
        max_seconds_per_k=scale.sweep_seconds or None,
    )
    fig = fig_nll_vs_components(sw)
    fig.savefig(out / "fig4.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return sw


#: Fig. 7 scene: the shipped model, the procedural chest of this seed, the planner's default goal.
FIG7_MODEL = "paper"
FIG7_CHEST_SEED = 0


def fig7_claims(trace, paper: dict | None = None) -> dict:
    """The paper's Fig. 7 statements checked against a best-bound ``trace`` (``trace[0]`` the
    nominal trajectory's eq.-10 bound, ``trace[i]`` the best after ``i`` iterations).

    ``below_after_paper_iterations``: whether the bound after the paper's number of iterations
    is below the paper's end value. The optimiser never raises the bound, so a run of fewer
    iterations that is already below decides it (``True``); one that is not yet below
    cannot (``None``); a run of at least that many iterations reads it off the trace.
    ``paper``: the values (default :data:`riskplan.app.reproduce.paper_values.MDN`).
    """
    from riskplan.app.reproduce.paper_values import MDN

    paper = MDN if paper is None else paper
    tr = [float(v) for v in trace]
    if not tr or not all(0.0 <= v <= 1.0 for v in tr):
        raise InvalidInputError(f"trace: expected probabilities in [0, 1], got {trace!r}")
    before = float(paper["collision_before"]["value"])
    after = float(paper["collision_after"]["value"])
    n_paper = int(paper["bo_iterations"]["value"])
    n = len(tr) - 1
    at = tr[min(n, n_paper)]
    if at < after:
        holds = True
    elif n >= n_paper:
        holds = False
    else:
        holds = None
    nominal, final = tr[0], tr[-1]
    return {
        "iterations": n,
        "paper_iterations": n_paper,
        "nominal": nominal,
        "paper_nominal": before,
        "nominal_minus_paper_points": 100.0 * (nominal - before),
        "final": final,
        "at_paper_iterations": at if n >= n_paper else None,
        "paper_after_below": after,
        "below_after_paper_iterations": holds,
        "reduction": 0.0 if nominal <= 0 else 1.0 - final / nominal,
        "paper_reduction_at_least": 1.0 - after / before,
    }


def _fig7_png(r: dict):
    import matplotlib.pyplot as plt

    from riskplan.app.reproduce.paper_values import MDN

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    for name, colour in (("nominal", "royalblue"), ("optimised", "darkorange")):
        t = r[name]
        a.plot(
            100 * np.asarray(t["bounds_eq9"]),
            "o-",
            ms=3,
            color=colour,
            label=f"{name}: eq. 10 bound {100 * t['bound_eq10']:.2f} %",
        )
    a.set_xlabel("configuration along the trajectory")
    a.set_ylabel("eq. 9 bound per configuration [%]")
    a.set_ylim(bottom=0)
    a.grid(alpha=0.3)
    a.legend(fontsize=8)
    a.set_title("trajectory before / after optimisation", fontsize=10)
    tr = 100 * np.asarray(r["trace"])
    b.plot(np.arange(len(tr)), tr, "o-", ms=3, label="riskplan (this run)")
    n_paper = MDN["bo_iterations"]["value"]
    b.plot(
        [0, n_paper],
        [100 * MDN["collision_before"]["value"], 100 * MDN["collision_after"]["value"]],
        "s--",
        color="gray",
        label=f"paper: about {100 * MDN['collision_before']['value']:.0f} %, "
        f"< {100 * MDN['collision_after']['value']:.0f} % after {n_paper}",
    )
    b.set_xlabel("Bayesian optimisation iteration")
    b.set_ylabel("best eq. 10 bound [%]")
    b.set_ylim(bottom=0)
    b.grid(alpha=0.3)
    b.legend(fontsize=8)
    b.set_title(f"bound per iteration ({len(tr) - 1} iterations run)", fontsize=10)
    fig.tight_layout()
    return fig


def _fig7_plotly(r: dict):
    """Interactive Fig. 7: the chest, the mixtures along both trajectories (3-D) and the trace."""
    from riskplan.app.outputs.chest_plan import trajectories_plotly
    from riskplan.kinematics import load_model
    from riskplan.planning.chest_scene import build_chest

    ch = build_chest(r["chest_seed"])
    return trajectories_plotly(
        ch.environment,
        load_model(r["model"]),
        {k: np.asarray(r[k]["configurations"]) for k in ("nominal", "optimised")},
        ch.to_world,
        samples=40,
        seed=0,
        title="Fig. 7: predicted mixtures along the nominal and the optimised trajectory (world frame)",
    )


@one_torch_thread
def run_fig7(out, scale: MDNScale, store, *, seed: int = 0, progress=None) -> dict:
    """Fig. 7 of the MDN paper: plan in the procedural chest, optimise the path's eq.-10 bound
    with ``scale.bo_iterations`` iterations of Bayesian optimisation, write ``out/fig7.png``
    (print) and ``out/fig7.html`` (interactive 3-D). The numbers are stored under
    ``mdn.fig7`` (a rerun reads them; a corrupted record raises
    :class:`~riskplan.errors.DataFormatError`). Returns the JSON numbers with
    :func:`fig7_claims` under ``claims`` and the figure paths under ``figures``. The stage's
    own timings (roadmap, query, optimisation and CPU seconds, as first computed) stay in the
    record's ``seconds`` (``riskplan reproduce`` copies them to ``timings.json``), out of the
    results, which depend on the seed and scale only."""
    report = progress or (lambda stage, done, total: None)
    found = store.get("mdn.fig7")
    if found is None:
        from riskplan.app.outputs.chest_plan import trajectory_record
        from riskplan.kinematics import load_model
        from riskplan.planning.bo import OptimiserConfig
        from riskplan.planning.chest import plan_chest
        from riskplan.planning.chest_scene import build_chest

        n = int(scale.bo_iterations)
        report("mdn: Fig. 7 (BO)", 0, n)
        cpu0 = time.process_time()
        plan_model = load_model(FIG7_MODEL)
        plan = plan_chest(
            plan_model,
            build_chest(FIG7_CHEST_SEED).base_environment,
            n_milestones=int(scale.milestones),
            optimiser=OptimiserConfig(iterations=n, n_candidates=int(scale.bo_candidates)),
            seed=seed,
            optimise_progress=lambda i, total, b: report("mdn: Fig. 7 (BO)", i, total),
        )
        res = plan.optimised
        robot_rows = None
        if scale.robot_executions:
            from riskplan.planning.validate import endpoint_warnings, validation_table

            report("mdn: Fig. 7 (robot executions)", 0, 1)
            robot_rows = validation_table(
                plan_model,
                {"nominal": plan.nominal, "optimised": res.trajectory},
                build_chest(FIG7_CHEST_SEED).base_environment,
                n_robot=int(scale.robot_executions),
                n_mixture=100_000,
                seed=seed,
                backend="serial",
            )
            for line in endpoint_warnings(robot_rows):
                log.warning("Fig. 7: %s", line)
            report("mdn: Fig. 7 (robot executions)", 1, 1)
        found = {
            "model": FIG7_MODEL,
            "chest_seed": FIG7_CHEST_SEED,
            "seed": int(seed),
            "goal_tip_base_frame": None if plan.goal_tip is None else plan.goal_tip.tolist(),
            "start": plan.start.tolist(),
            "goal": plan.goal.tolist(),
            "roadmap": {"milestones": plan.roadmap.n_vertices, "edges": plan.roadmap.n_edges},
            "settings": json_safe(plan.settings),
            "nominal": trajectory_record(
                "nominal", plan.nominal, plan.nominal_bounds, plan.nominal_bound
            ),
            "optimised": trajectory_record("optimised", res.trajectory, res.bounds, res.bound),
            "trace": res.trace.tolist(),
            "chosen": [int(c) for c in res.chosen],
            "accepted": [bool(a) for a in res.accepted],
            "evaluations": int(res.evaluations),
            "robot": robot_rows,
            "seconds": {
                **{k: float(v) for k, v in plan.timings.items()},
                "cpu_s": time.process_time() - cpu0,
            },
        }
        store.put("mdn.fig7", found)
        report("mdn: Fig. 7 (BO)", n, n)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from riskplan.io import atomic_path

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fig = _fig7_png(found)
    with atomic_path(out / "fig7.png", suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    plt.close(fig)
    with atomic_path(out / "fig7.html", suffix=".html") as tmp:
        _fig7_plotly(found).write_html(str(tmp), include_plotlyjs="directory", full_html=True)
    return {
        **{k: v for k, v in found.items() if k != "seconds"},
        "claims": fig7_claims(found["trace"]),
        "figures": {"fig7": "mdn/fig7.png", "fig7_html": "mdn/fig7.html"},
    }


def json_safe(obj):
    """``obj`` with NumPy scalars and tuples turned into plain JSON values."""
    import json

    return json.loads(json.dumps(obj, default=lambda v: v.item() if hasattr(v, "item") else str(v)))
