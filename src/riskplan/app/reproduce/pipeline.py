"""``riskplan reproduce``: both papers' evaluations as one resumable job.

* ``deformable`` — Patil, van den Berg & Alterovitz, RSS 2011, §V: Fig. 6 for the needle
  and the manipulation scenario (:mod:`riskplan.app.reproduce.deformable`), the paper's claims
  checked by numbers, LQG-MP's predicted ``P(success)`` beside the measured rate, and the
  single executions of Figs. 4, 5 and 7(c-f).
* ``mdn`` — the MDN paper: Fig. 4 (NLL vs K), Fig. 5, MDN vs Cosserat timing, and Fig. 7
  (Bayesian optimisation of a chest-cavity path, the "about 15 % → below 7 % after 50
  iterations" claim) (:mod:`riskplan.app.reproduce.mdn`); stage ``robot-risk``: risks from
  the learned model against the robot's collision rates
  (:mod:`riskplan.app.reproduce.risk_calibration`).

Every parallel stage runs on one :class:`riskplan.parallel.TaskPool` opened for the whole
job, so the worker processes (or the Ray connection) start once, not once per stage.

Outputs in ``out``: ``results.json`` (every number, a pure function of paper, scale and
seed, so a rerun or a resumed run writes the same file whatever the backend),
``timings.json`` (wall-clock times, which vary), ``report.html`` with PNG figures and
interactive plotly pages, and ``store/`` (the finished work units,
:class:`~riskplan.app.store.ResultStore`). Rerunning the same command continues
from ``store/``; a store of another configuration or a corrupted record raises
:class:`~riskplan.errors.DataFormatError` naming it.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict
from pathlib import Path

from riskplan._validation import check_workers
from riskplan.errors import InvalidInputError

log = logging.getLogger(__name__)

__all__ = ["PAPERS", "SCALE_NAMES", "STAGES", "reproduce", "resolve_scale"]

PAPERS = ("mdn", "deformable", "all")
SCALE_NAMES = ("smoke", "paper")
#: ``figures``: the papers' figures and claims; ``calibration``: LQG-MP's predicted
#: P(success) against measured closed-loop success (:mod:`riskplan.app.reproduce.calibration`,
#: deformable paper only, its own sizes: ``calibration_scale``); ``sensitivity``: the
#: needle's Fig. 6 under actuation-noise and interaction-force scales ×0.5, ×1, ×2 and the
#: other reading of the cases (:func:`riskplan.app.reproduce.needle_study.sensitivity`, its own
#: sizes: :func:`_sensitivity_scales`); ``needle3d``: the 3-D needle (beyond the paper).
#: ``calibration-needle`` / ``calibration-manipulation``: the calibration of one scenario
#: (each a stage of its own that fits an hour at the ``full`` calibration scale; the same
#: store records as ``calibration``, which then assembles both from the store).
#: ``control-variants``: LQG against the UKF and iLQR on the selected RRT plans
#: (:mod:`riskplan.app.reproduce.control_variants`, beyond the paper).
#: ``robot-risk``: the chest risks against the robot's collision rates (MDN paper; its sizes:
#: :data:`riskplan.app.reproduce.robot_risk.ROBOT_RISK_FOR`, or ``robot_risk_scale``).
STAGES = (
    "figures",
    "calibration",
    "calibration-needle",
    "calibration-manipulation",
    "sensitivity",
    "needle3d",
    "control-variants",
    "robot-risk",
)
#: the calibration sizes a named scale uses unless ``calibration_scale`` names others
_CALIBRATION_FOR = {"smoke": "smoke", "paper": "full"}
SCENARIOS = ("needle", "manipulation")


def _sensitivity_scales() -> dict:
    """The sizes of the sensitivity stage per named scale: ``smoke`` (seconds) and, for
    ``paper``, the documented reduced scale of docs/reproduce.md (5 candidates per set, 100
    executions per bar, 8 linearisation draws, 500 LQG-MP goal samples, 5 plans per tree;
    about 25 min on two cores), each variant a Fig. 6 of the needle."""
    from riskplan.app.reproduce.deformable import ScenarioScale

    return {
        "smoke": ScenarioScale(
            n_candidates=1,
            n_executions=10,
            batch_size=10,
            lin_samples=4,
            goal_samples=100,
            plans_per_tree=1,
        ),
        "paper": ScenarioScale(
            n_candidates=5,
            n_executions=100,
            batch_size=50,
            lin_samples=8,
            goal_samples=500,
            plans_per_tree=5,
        ),
    }


def resolve_scale(scale) -> tuple[str, dict]:
    """``(name, {"needle": ScenarioScale, "manipulation": ScenarioScale, "mdn": MDNScale})``
    for a scale name (:data:`SCALE_NAMES`) or an explicit dict of those (name ``"custom"``)."""
    from riskplan.app.reproduce.deformable import SCALES
    from riskplan.app.reproduce.mdn import MDN_SCALES

    if isinstance(scale, str):
        if scale not in SCALE_NAMES:
            raise InvalidInputError(
                f"scale: expected one of {', '.join(SCALE_NAMES)}, got {scale!r}"
            )
        return scale, {**SCALES[scale], "mdn": MDN_SCALES[scale]}
    if isinstance(scale, dict):
        return "custom", dict(scale)
    raise InvalidInputError(
        f"scale: expected one of {', '.join(SCALE_NAMES)} or a dict of scales, got {scale!r}"
    )


def _check(paper, backend, workers, ray_address):
    from riskplan.parallel import BACKENDS, check_ray_address

    if paper not in PAPERS:
        raise InvalidInputError(f"paper: expected one of {', '.join(PAPERS)}, got {paper!r}")
    if backend not in BACKENDS:
        raise InvalidInputError(f"backend: expected one of {', '.join(BACKENDS)}, got {backend!r}")
    check_workers(workers)
    if ray_address is not None:
        if backend != "ray":
            raise InvalidInputError(
                f"address: only used with backend 'ray', got backend {backend!r}"
            )
        check_ray_address(ray_address)  # BackendUnavailableError within seconds


def reproduce(
    out,
    *,
    paper: str = "all",
    scale="smoke",
    backend: str = "local",
    ray_address: str | None = None,
    workers: int | None = None,
    seed: int = 0,
    progress=None,
    stages=("figures",),
    calibration_scale: str | None = None,
    robot_risk_scale: str | None = None,
) -> dict:
    """Run (or continue) the reproduction and write ``out/results.json`` and ``out/report.html``.

    Parameters
    ----------
    out : output folder (created; an existing one is continued).
    paper : ``"mdn"``, ``"deformable"`` or ``"all"``.
    scale : ``"smoke"`` (minutes), ``"paper"`` (the papers' sizes) or a dict of scales.
    backend, ray_address, workers : :mod:`riskplan.parallel` (results do not depend on them).
    seed : master seed.
    progress : optional ``progress(stage, done, total)`` callback.
    stages : which of :data:`STAGES` run (default the figures only). The stage list is not
        part of the store's configuration, so stages can run one after another into the
        same ``out`` (each resumes its own records); ``results.json`` holds what this call ran.
    The ``sensitivity`` stage (needle) runs at :func:`_sensitivity_scales` of ``scale``
        (``custom`` scales: ``smoke``) into ``out/sensitivity`` (resumable, one store per
        variant).
    calibration_scale : sizes of the calibration stage
        (:data:`riskplan.app.reproduce.calibration.CALIBRATION_SCALES`: ``smoke``,
        ``reduced``, ``full``); ``None``: ``smoke`` for scale ``smoke``, ``full`` for
        ``paper`` (a dict scale names its own under ``"calibration"``, or gets ``smoke``).
    robot_risk_scale : sizes of the ``robot-risk`` stage
        (:data:`riskplan.app.reproduce.risk_calibration.RISK_STUDY_SCALES`: ``smoke``,
        ``reduced``, ``full``); ``None``: ``smoke`` for scale ``smoke``, ``full`` for ``paper``.
        The stage runs into ``out/robot-risk`` with a store of its own (resumable).

    Returns the results dict (what ``results.json`` holds). Raises
    :class:`~riskplan.errors.InvalidInputError` for bad arguments,
    :class:`~riskplan.errors.BackendUnavailableError` for an unreachable Ray address and
    :class:`~riskplan.errors.DataFormatError` for a corrupted or foreign results store.
    """
    from riskplan.io import check_output_folder, output_lock

    _check(paper, backend, workers, ray_address)
    stages = (stages,) if isinstance(stages, str) else tuple(stages)
    if not stages or any(s not in STAGES for s in stages):
        raise InvalidInputError(f"stages: expected names from {', '.join(STAGES)}, got {stages!r}")
    if robot_risk_scale is not None:
        from riskplan.app.reproduce.risk_calibration import RISK_STUDY_SCALES

        if robot_risk_scale not in RISK_STUDY_SCALES:
            raise InvalidInputError(
                f"robot_risk_scale: expected one of {', '.join(RISK_STUDY_SCALES)}, "
                f"got {robot_risk_scale!r}"
            )
    out = check_output_folder(out, "out")
    # one writer per output folder: a second run into it stops at once (the store's own
    # checks keep records consistent, the lock keeps results.json and the report one run's)
    with output_lock(out, "output folder"):
        return _reproduce(
            out, paper, scale, backend, ray_address, workers, seed, progress, stages,
            calibration_scale, robot_risk_scale,
        )  # fmt: skip


def _sensitivity_stage(scale_name, out, seed, backend, workers, progress) -> dict:
    """The needle's sensitivity study at the scale's size, as ``results`` stores it: its
    scale and, per variant and case, the success rate of each method (``None``: not
    applicable)."""
    from riskplan.app.reproduce.needle_study import sensitivity

    sscale = _sensitivity_scales().get(scale_name, _sensitivity_scales()["smoke"])
    sens = sensitivity(
        sscale,
        out / "sensitivity",
        seed=seed,
        backend=backend,
        workers=workers,
        progress=progress,
    )
    runs = sens.pop("runs")
    sens["scale"] = asdict(sscale)
    # per variant and case the success rate of each method (None: not applicable)
    sens["cases"] = {
        tag: {
            c: {m: (None if v is None else v["rate"]) for m, v in ms.items()}
            for c, ms in r["cases"].items()
        }
        for tag, r in runs.items()
    }
    return json.loads(json.dumps(sens))


def _beyond_stages(stages, results, timings, out, store, scale_name, seed, progress) -> None:
    """The stages beyond the deformable paper, into ``results`` and ``timings``:
    ``needle3d`` (:mod:`riskplan.app.reproduce.needle3d`) and ``control-variants``
    (:mod:`riskplan.app.reproduce.control_variants`)."""
    if "needle3d" in stages:
        from riskplan.app.reproduce.needle3d import run_needle3d

        t0 = time.perf_counter()
        results["needle3d"] = run_needle3d(out, scale_name, seed=seed)
        timings["needle3d_s"] = time.perf_counter() - t0
    if "control-variants" in stages:
        from riskplan.app.reproduce.control_variants import run_control_variants

        t0 = time.perf_counter()
        results["control_variants"] = run_control_variants(
            store, scale_name, seed=seed, progress=progress
        )
        timings["control_variants_s"] = time.perf_counter() - t0


def _mdn_figures(
    results, timings, out, scale, store, seed, workers, backend, ray_address, progress
) -> None:
    """The MDN paper's figures (Figs. 4, 5, timing; Fig. 7) into ``results["mdn"]`` and their
    seconds into ``timings`` (:mod:`riskplan.app.reproduce.mdn`)."""
    from riskplan.app.reproduce.mdn import run_fig7, run_mdn

    t0 = time.perf_counter()
    results["mdn"] = run_mdn(
        out / "mdn",
        scale,
        store,
        seed=seed,
        workers=workers,
        backend=backend,
        ray_address=ray_address,
        progress=progress,
    )
    timings["mdn_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    results["mdn"]["fig7"] = run_fig7(out / "mdn", scale, store, seed=seed, progress=progress)
    timings["mdn_fig7_s"] = time.perf_counter() - t0
    first = store.get("mdn.fig7")["seconds"]  # as first computed (a rerun reads them)
    timings["mdn_fig7_first_run"] = first


def _robot_risk_stage(
    results, timings, out, scale_name, seed, progress, backend, workers, rr_scale
):
    """The ``robot-risk`` stage into ``results["mdn"]["robot_risk"]`` and its seconds into
    ``timings["robot_risk_s"]`` (:func:`riskplan.app.reproduce.robot_risk.robot_risk_stage`)."""
    from riskplan.app.reproduce.robot_risk import robot_risk_stage

    t0 = time.perf_counter()
    results.setdefault("mdn", {})["robot_risk"] = robot_risk_stage(
        out,
        scale_name,
        seed=seed,
        progress=progress,
        backend=backend,
        workers=workers,
        robot_risk_scale=rr_scale,
    )
    timings["robot_risk_s"] = time.perf_counter() - t0


def _reproduce(
    out, paper, scale, backend, ray_address, workers, seed, progress, stages, calibration_scale,
    robot_risk_scale=None,
) -> dict:  # fmt: skip
    import riskplan
    from riskplan.app.reproduce.calibration import CALIBRATION_SCALES
    from riskplan.app.store import ResultStore
    from riskplan.io import write_json_atomic
    from riskplan.parallel import TaskPool

    scale_name, scales = resolve_scale(scale)
    calib = scales.pop("calibration", None)
    if calibration_scale is not None or calib is None:
        cname = calibration_scale or _CALIBRATION_FOR.get(scale_name, "smoke")
        if cname not in CALIBRATION_SCALES:
            raise InvalidInputError(
                f"calibration_scale: expected one of {', '.join(CALIBRATION_SCALES)}, got {cname!r}"
            )
        calib = CALIBRATION_SCALES[cname]
    seed = int(seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    config = {
        "paper": paper,
        "scale": scale_name,
        "sizes": {k: asdict(v) for k, v in scales.items()},
        "calibration_sizes": {k: asdict(v) for k, v in calib.items()},
        "seed": seed,
        "version": riskplan.__version__,
    }
    store = ResultStore(out / "store", config)
    results: dict = {"config": config}
    figures = "figures" in stages
    timings: dict = {"backend": backend, "workers": workers}
    with TaskPool(backend, workers, ray_address) as pool:  # one pool for every stage
        if figures and paper in ("deformable", "all"):
            from riskplan.app.reproduce.deformable import run_scenario

            results["deformable"] = {}
            for name in SCENARIOS:
                t0 = time.perf_counter()
                results["deformable"][name] = run_scenario(
                    name,
                    scales[name],
                    store,
                    seed=seed,
                    backend=backend,
                    workers=workers,
                    ray_address=ray_address,
                    progress=progress,
                    pool=pool,
                )
                timings[f"deformable_{name}_s"] = time.perf_counter() - t0
        if figures and paper in ("mdn", "all"):
            mdn_args = (out, scales["mdn"], store, seed, workers, backend, ray_address, progress)
            _mdn_figures(results, timings, *mdn_args)
        calibrated = [
            name for name in SCENARIOS if "calibration" in stages or f"calibration-{name}" in stages
        ]
        if paper in ("deformable", "all") and calibrated:
            from riskplan.app.reproduce.calibration import run_calibration

            results.setdefault("deformable", {})
            for name in calibrated:
                t0 = time.perf_counter()
                results["deformable"].setdefault(name, {})["calibration"] = run_calibration(
                    name,
                    calib[name],
                    store,
                    seed=seed,
                    backend=backend,
                    workers=workers,
                    ray_address=ray_address,
                    progress=progress,
                    pool=pool,
                    cost=timings.setdefault(f"calibration_{name}_cost", {}),
                )
                timings[f"calibration_{name}_s"] = time.perf_counter() - t0
        if paper in ("deformable", "all") and "sensitivity" in stages:
            t0 = time.perf_counter()
            sens = _sensitivity_stage(scale_name, out, seed, backend, workers, progress)
            results.setdefault("deformable", {}).setdefault("needle", {})["sensitivity"] = sens
            timings["sensitivity_needle_s"] = time.perf_counter() - t0
        if paper in ("deformable", "all"):
            _beyond_stages(stages, results, timings, out, store, scale_name, seed, progress)
        if paper in ("mdn", "all") and "robot-risk" in stages:
            rr_args = (out, scale_name, seed, progress, backend, workers, robot_risk_scale)
            _robot_risk_stage(results, timings, *rr_args)
        timings["process_pools_started"] = pool.pools_started
    write_json_atomic(out / "results.json", results, sort_keys=True)
    write_json_atomic(out / "timings.json", timings, sort_keys=True)
    from riskplan.app.reproduce.report import write_report

    t0 = time.perf_counter()
    write_report(out, results, store, timings, seed=seed)
    timings["report_s"] = time.perf_counter() - t0
    write_json_atomic(out / "timings.json", timings, sort_keys=True)
    log.info("reproduce: results in %s", out)
    return json.loads(json.dumps(results))
