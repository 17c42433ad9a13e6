"""Demo stage "kinematics": train a small MDN, sweep K (Fig. 4), evaluate (Fig. 5).

Uses ``ctx["train_path"]`` / ``ctx["test_path"]`` from the robot stage; if they are
absent, generates the ``small`` preset with :mod:`riskplan.datasets`. Sets
``ctx["model"]`` (:class:`~riskplan.kinematics.mdn.MDNModel`) and ``ctx["model_path"]``.
Budget: about 90 s on two cores (few epochs; the quality runs are in docs/results.md).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from riskplan.app.report import Report
from riskplan.threads import one_torch_thread

log = logging.getLogger(__name__)

DEMO_COMPONENTS = 5
SWEEP_COMPONENTS = (1, 2, 3, 4, 5)
# The small preset has few configurations: small batches give enough steps per epoch.
TRAIN = dict(
    hidden=(64, 64),
    head_hidden=(32,),
    batch_size=16,
    points_per_config=256,
    lr=3e-3,
    early_stop_patience=15,
    lr_patience=5,
)
MAIN_EPOCHS = 400
SWEEP_EPOCHS = 150
# wall-clock seconds of training (stop at the first epoch end past it): keeps the stage near 60 s
MAIN_TIME_BUDGET = 25.0
SWEEP_TIME_BUDGET = 8.0


def _data_paths(ctx: dict, seed: int, workers) -> tuple[Path, Path] | None:
    train, test = ctx.get("train_path"), ctx.get("test_path")
    if train and test and Path(train).is_file() and Path(test).is_file():
        return Path(train), Path(test)
    try:
        from riskplan.datasets import generate_splits
        from riskplan.robots import load_robot
    except ImportError as exc:
        log.warning(
            "kinematics demo: no data set in ctx and riskplan.datasets unavailable (%s)", exc
        )
        return None
    robot = ctx.get("robot") or load_robot("paper")
    paths = generate_splits(
        robot, "small", Path(ctx["out"]) / "data" / "small", seed=seed, workers=workers
    )
    ctx["train_path"], ctx["test_path"] = paths["train"], paths["test"]
    return Path(paths["train"]), Path(paths["test"])


@one_torch_thread
def run(report: Report, ctx: dict, *, seed: int, workers: int | None) -> None:

    from riskplan.kinematics.data import read_point_clouds
    from riskplan.kinematics.plotting import (
        fig_nll_vs_components,
        fig_samples_vs_truth,
        plotly_samples_vs_truth,
    )
    from riskplan.kinematics.sweep import sweep
    from riskplan.kinematics.training import TrainConfig, train

    sec = report.section("Learned kinematics: mixture density network (MDN paper, Figs. 4-5)")
    paths = _data_paths(ctx, seed, workers)
    if paths is None:
        Report.text(
            sec,
            "Skipped: no point-cloud data set available (the robot/data-set stages did not provide one).",
        )
        return
    train_path, test_path = paths
    out = Path(ctx["out"]) / "kinematics"
    train_data = read_point_clouds(train_path)
    test_data = read_point_clouds(test_path)

    t0 = time.perf_counter()
    cfg = TrainConfig(n_components=DEMO_COMPONENTS, epochs=MAIN_EPOCHS, seed=seed, **TRAIN)
    model_path = out / "model"
    # the time budget keeps the demo short on slow machines: it shortens the run, never lengthens it
    res = train(train_data, cfg, out=model_path, max_seconds=MAIN_TIME_BUDGET, overwrite=True)
    model, history = res.model, res.history
    t_train = time.perf_counter() - t0
    ctx["model"], ctx["model_path"] = model, model_path

    from riskplan.kinematics.evaluation import evaluate_for_report

    ev = evaluate_for_report(model, test_data, seed)
    Report.text(
        sec,
        f"Trained a K={model.n_components} MDN on {train_data.n_configs} configurations x {train_data.n_points} points "
        f"({len(history)} epochs, {t_train:.0f} s) and evaluated it on {ev.n_configs} test configurations. "
        "NLL is in nats per point with positions in metres (lower is better).",
    )
    rows = [["test NLL [nats/point]", ev.nll], ["Chamfer distance [mm]", ev.chamfer * 1e3]]
    rows += [[f"HDR coverage at level {a:g} (target {a:g})", c] for a, c in ev.calibration.items()]
    Report.table(sec, ["measure", "value"], rows, caption="Evaluation on the test set")
    report.figure(
        sec,
        fig_samples_vs_truth(model, test_data, n_configs=2, n_samples=1500, seed=seed),
        "kinematics_fig5",
        "Fig. 5: samples of the predicted mixture (red) vs ground-truth points (blue), two random test configurations.",
    )
    report.plotly(
        sec,
        plotly_samples_vs_truth(model, test_data, n_configs=2, n_samples=1500, seed=seed),
        "kinematics_fig5",
        "Fig. 5",
    )

    sweep_cfg = TrainConfig(epochs=SWEEP_EPOCHS, seed=seed, **TRAIN)
    sw = sweep(
        train_path,
        test_path,
        list(SWEEP_COMPONENTS),
        sweep_cfg,
        out=out / "sweep",
        workers=workers,
        max_seconds_per_k=SWEEP_TIME_BUDGET,
    )
    report.figure(
        sec,
        fig_nll_vs_components(sw),
        "kinematics_fig4",
        f"Fig. 4: test NLL vs number of components (at most {SWEEP_EPOCHS} epochs or {SWEEP_TIME_BUDGET:g} s each; recommended K={sw.recommended}).",
    )
    Report.table(
        sec,
        ["K", "test NLL", "collapsed components"],
        [[e.n_components, e.test_nll, ", ".join(map(str, e.collapsed)) or "-"] for e in sw.entries],
        caption=f"K sweep: {sw.rule}",
    )
