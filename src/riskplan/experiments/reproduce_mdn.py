"""The MDN paper's results for ``riskplan reproduce`` (Thompson, Cho, Brown & Kuntz): Fig. 4
(test NLL against the number of mixture components K), Fig. 5 (samples of the predicted
mixture against ground-truth points) and the MDN-vs-Cosserat timing of §V, computed with
the library's own data-set generator (simulated robot and cameras), trainer and sweep.

Fig. 7 (Bayesian optimisation of a chest-cavity path, 15 % → < 7 %) needs the chest
planner (``riskplan plan chest``); where that is not installed the section says so.

Numbers that depend on wall-clock time (training budgets, timings) are stored once in the
:class:`~riskplan.experiments.store.ResultStore` when computed, so a rerun reports the
same values.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from riskplan.errors import InvalidInputError

log = logging.getLogger(__name__)

__all__ = ["MDN_SCALES", "MDNScale", "run_mdn"]


@dataclass(frozen=True)
class MDNScale:
    """Sizes of the MDN part. ``preset``: data-set protocol (:data:`riskplan.datasets.PRESETS`);
    ``components``: the K of Fig. 4; ``n_components``: K of the Fig. 5 model; ``epochs`` /
    ``sweep_epochs``: at most this many epochs; ``train_seconds`` / ``sweep_seconds``:
    wall-clock budgets (``0`` = none); ``timing_configs``: random configurations timed."""

    preset: str = "small"
    components: tuple = (1, 2, 3, 5)
    n_components: int = 5
    epochs: int = 400
    sweep_epochs: int = 150
    train_seconds: float = 20.0
    sweep_seconds: float = 5.0
    timing_configs: int = 200

    def __post_init__(self):
        if not self.components or min(self.components) < 1:
            raise InvalidInputError(
                f"components: expected positive integers, got {self.components!r}"
            )
        object.__setattr__(self, "components", tuple(int(k) for k in self.components))


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
    ),
}

TRAIN = dict(
    hidden=(64, 64),
    head_hidden=(32,),
    batch_size=16,
    points_per_config=256,
    lr=3e-3,
    early_stop_patience=15,
    lr_patience=5,
)


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


def run_mdn(
    out, scale: MDNScale, store, *, seed: int = 0, workers: int | None = None, progress=None
) -> dict:
    """Figs. 4-5 and the timing of the MDN paper into ``out`` (PNG + plotly pages written
    when first computed). Returns the JSON numbers (also stored under ``mdn.results``)."""
    found = store.get("mdn.results")
    if found is not None:
        return found
    import torch

    from riskplan.datasets import generate_splits
    from riskplan.kinematics.data import read_point_clouds
    from riskplan.kinematics.evaluation import evaluate
    from riskplan.kinematics.plotting import (
        fig_nll_vs_components,
        fig_samples_vs_truth,
        plotly_samples_vs_truth,
    )
    from riskplan.kinematics.sweep import sweep
    from riskplan.kinematics.training import TrainConfig, train
    from riskplan.robots import load_robot

    torch.set_num_threads(1)
    report = progress or (lambda stage, done, total: None)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    steps = 4
    report("mdn: data set", 0, steps)
    robot = load_robot("paper")
    paths = generate_splits(
        robot, scale.preset, out / "data" / scale.preset, seed=seed, workers=workers
    )
    train_data, test_data = read_point_clouds(paths["train"]), read_point_clouds(paths["test"])
    report("mdn: train (Fig. 5)", 1, steps)
    cfg = TrainConfig(n_components=scale.n_components, epochs=scale.epochs, seed=seed, **TRAIN)
    res = train(train_data, cfg, out=out / "model", max_seconds=scale.train_seconds or None)
    model = res.model
    ev = evaluate(
        model,
        test_data,
        n_samples=2048,
        chamfer_points=1024,
        seed=seed,
        max_configs=min(test_data.n_configs, 60),
    )
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = fig_samples_vs_truth(model, test_data, n_configs=2, n_samples=1500, seed=seed)
    fig.savefig(out / "fig5.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    plotly_samples_vs_truth(model, test_data, n_configs=2, n_samples=1500, seed=seed).write_html(
        out / "fig5.html", include_plotlyjs="directory", full_html=True
    )
    report("mdn: K sweep (Fig. 4)", 2, steps)
    sw = sweep(
        paths["train"],
        paths["test"],
        list(scale.components),
        TrainConfig(epochs=scale.sweep_epochs, seed=seed, **TRAIN),
        out=out / "sweep",
        workers=workers or 2,
        max_seconds_per_k=scale.sweep_seconds or None,
    )
    fig = fig_nll_vs_components(sw)
    fig.savefig(out / "fig4.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    report("mdn: timing", 3, steps)
    timing = _timing(model, robot, scale.timing_configs, seed)
    report("mdn: timing", 4, steps)
    result = {
        "train_configs": int(train_data.n_configs),
        "test_configs": int(test_data.n_configs),
        "epochs": len(res.history),
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
