"""Choosing the number of mixture components (MDN paper, section IV, Fig. 4).

For each ``K`` a model is trained on the training set and scored on the test set:
test NLL (Fig. 4) and the per-component weight statistics over the test
configurations, from which mode collapse is detected (components whose weight stays
below ``collapse_threshold`` on 99 % of the configurations, see
:func:`riskplan.kinematics.evaluation.mode_collapse`).

Recommended ``K`` (our rule; the paper picks "the minimum number of components
necessary to sufficiently minimize the negative log-likelihood ... while avoiding mode
collapse"): among the ``K`` without mode collapse, the smallest whose test NLL is within
``nll_tolerance`` nats per point of the best test NLL of all ``K``. NLL differences do not
depend on the length unit, so the tolerance is unit-free. If every ``K`` collapses, the
rule is applied to all ``K``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from riskplan._validation import check_count_list, check_workers
from riskplan.errors import InvalidInputError
from riskplan.kinematics.training import TrainConfig
from riskplan.threads import one_torch_thread

log = logging.getLogger(__name__)

DEFAULT_COLLAPSE_THRESHOLD = 0.01
DEFAULT_NLL_TOLERANCE = 0.05


def parse_components(spec: str) -> list[int]:
    """``"1-10"``, ``"1,2,5"`` or ``"3"`` → sorted unique list of positive ints."""
    out: set[int] = set()
    try:
        for part in str(spec).split(","):
            part = part.strip()
            if "-" in part:
                a, b = (int(x) for x in part.split("-", 1))
                if a > b:
                    raise ValueError(part)
                out.update(range(a, b + 1))
            elif part:
                out.add(int(part))
    except ValueError as exc:
        raise InvalidInputError(
            f"components: expected e.g. '1-10' or '1,3,5', got {spec!r}"
        ) from exc
    return list(check_count_list(sorted(out), f"components {spec!r}"))


@dataclass
class SweepEntry:
    n_components: int
    test_nll: float
    val_nll: float
    weight_mean: list[float]
    weight_p99: list[float]
    collapsed: list[int]
    epochs: int
    seconds: float
    model_path: str
    error: str = ""  # why this K produced no model (training diverged), else empty


@dataclass
class SweepResult:
    entries: list[SweepEntry]
    recommended: int
    collapse_threshold: float
    nll_tolerance: float
    rule: str = field(default="")

    @property
    def components(self) -> list[int]:
        return [e.n_components for e in self.entries]

    @property
    def test_nll(self) -> list[float]:
        return [e.test_nll for e in self.entries]

    def to_json(self) -> dict:
        return {
            "components": self.components,
            "test_nll": self.test_nll,
            "recommended_components": self.recommended,
            "collapse_threshold": self.collapse_threshold,
            "nll_tolerance": self.nll_tolerance,
            "rule": self.rule,
            "nll_units": "nats per point, positions in metres",
            "entries": [e.__dict__ for e in self.entries],
        }


def recommend(components, test_nll, collapsed, nll_tolerance: float = DEFAULT_NLL_TOLERANCE) -> int:
    """The rule of this module: smallest non-collapsed ``K`` within ``nll_tolerance`` of the best NLL."""
    components = list(components)
    nll = np.asarray(test_nll, dtype=np.float64)
    if len(components) == 0 or len(components) != len(nll):
        raise InvalidInputError(
            "recommend: components and test_nll must be non-empty and of equal length"
        )
    if not np.isfinite(nll).any():
        raise InvalidInputError("recommend: no K has a finite test NLL")
    best = np.nanmin(nll)
    finite = [i for i in range(len(components)) if np.isfinite(nll[i])]
    ok = [i for i in finite if not collapsed[i]] or finite
    cand = [components[i] for i in ok if nll[i] <= best + nll_tolerance]
    if not cand:  # all non-collapsed K are far from the best: take the best among them
        i = min(ok, key=lambda j: nll[j])
        return components[i]
    return min(cand)


@one_torch_thread
def _sweep_one(task: tuple) -> dict:
    """Train and score one ``K`` (module level so process pools can run it)."""
    import time

    from riskplan.errors import ConvergenceError
    from riskplan.kinematics.data import read_point_clouds
    from riskplan.kinematics.evaluation import component_weight_stats, mode_collapse, nll_per_config
    from riskplan.kinematics.training import train

    train_path, test_path, K, cfg_json, out_dir, threshold, max_seconds = task
    t0 = time.perf_counter()
    cfg = TrainConfig.from_json({**cfg_json, "n_components": K})
    train_data = read_point_clouds(train_path)
    test_data = read_point_clouds(test_path)
    try:
        res = train(train_data, cfg, out=out_dir, max_seconds=max_seconds, overwrite=True)
    except ConvergenceError as exc:  # one diverging K must not sink the whole sweep; it is reported
        log.warning("K=%d: %s", K, exc)
        return {
            "n_components": K,
            "test_nll": float("nan"),
            "val_nll": float("nan"),
            "weight_mean": [],
            "weight_p99": [],
            "collapsed": [],
            "epochs": 0,
            "seconds": time.perf_counter() - t0,
            "model_path": "",
            "error": str(exc),
        }
    nll = float(nll_per_config(res.model, test_data).mean())
    ws = component_weight_stats(res.model, test_data.displacements)
    return {
        "n_components": K,
        "test_nll": nll,
        "val_nll": res.best_val_nll,
        "weight_mean": ws["mean"].tolist(),
        "weight_p99": ws["p99"].tolist(),
        "collapsed": mode_collapse(ws["p99"], threshold),
        "epochs": len(res.history),
        "seconds": time.perf_counter() - t0,
        "model_path": str(out_dir),
    }


def sweep(
    train_path,
    test_path,
    components,
    config: TrainConfig | None = None,
    *,
    out,
    workers: int | None = 1,
    backend: str | None = None,
    ray_address: str | None = None,
    collapse_threshold: float = DEFAULT_COLLAPSE_THRESHOLD,
    nll_tolerance: float = DEFAULT_NLL_TOLERANCE,
    on_result=None,
    max_seconds_per_k: float | None = None,
) -> SweepResult:
    """Train one model per ``K`` in ``components`` and score it on ``test_path`` (Fig. 4).

    Models go to ``out/K{K}/``. ``workers > 1`` trains several ``K`` at once in
    processes; ``backend`` (``None``: ``"local"`` when more than one worker runs, else
    ``"serial"``), ``ray_address``: :func:`riskplan.parallel.map_tasks` (``workers=None``:
    one per core, as everywhere). ``on_result(index, entry_dict)`` reports each finished ``K``.
    ``max_seconds_per_k``: wall-clock budget of each training (see ``train(max_seconds=)``).
    Both data sets are checked (readable, non-empty, same robot) before any training.
    """
    from riskplan.kinematics.data import check_compatible, read_point_clouds
    from riskplan.parallel import effective_workers, map_tasks

    components = (
        parse_components(components)
        if isinstance(components, str)
        else sorted(set(check_count_list(components, "components")))
    )
    if not 0.0 < collapse_threshold < 1.0:
        raise InvalidInputError(f"collapse_threshold: expected in (0, 1), got {collapse_threshold}")
    if not nll_tolerance >= 0.0:
        raise InvalidInputError(f"nll_tolerance: expected >= 0, got {nll_tolerance}")
    check_workers(workers)
    from riskplan.io import check_output_folder

    check_output_folder(out, "out")
    config = config or TrainConfig()
    config.validate()
    tr, te = read_point_clouds(train_path), read_point_clouds(test_path)
    check_compatible(tr, te, what="test set")
    del tr, te
    out = Path(out)
    tasks = [
        (
            str(train_path),
            str(test_path),
            K,
            config.to_json(),
            str(out / f"K{K}"),
            collapse_threshold,
            max_seconds_per_k,
        )
        for K in components
    ]
    if backend is None:
        # workers=None is one per core, as everywhere (riskplan.parallel.effective_workers)
        backend = (
            "serial" if len(tasks) == 1 or effective_workers("local", workers) <= 1 else "local"
        )
    results = map_tasks(
        _sweep_one,
        tasks,
        backend=backend,
        workers=workers,
        chunksize=1,
        ray_address=ray_address,
        on_result=on_result,
    )
    entries = [SweepEntry(**r) for r in results]
    rec = recommend(
        components, [e.test_nll for e in entries], [e.collapsed for e in entries], nll_tolerance
    )
    rule = (
        f"smallest K without mode collapse (no component with weight < {collapse_threshold:g} on 99% of test "
        f"configurations) whose test NLL is within {nll_tolerance:g} nats/point of the best"
    )
    return SweepResult(entries, rec, collapse_threshold, nll_tolerance, rule)
