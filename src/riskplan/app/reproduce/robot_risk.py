"""The ``robot-risk`` stage of ``riskplan reproduce`` (beyond the MDN paper): the chest
risk study of :mod:`riskplan.app.reproduce.risk_calibration` run into ``out/robot-risk``,
its summary in ``results.json`` (``mdn.robot_risk.<risk>.{mae_band, brier, n_band, n,
spearman}``) and its calibration plot and table in ``report.html``.

The stage's store (``out/robot-risk/store``) has the configuration of ``riskplan plan
chest-risk-study``'s store, so either continues the other's folder; sizes: ``smoke`` with
``--scale smoke``, ``full`` (the documented scale of docs/reproduce.md) with ``--scale
paper``, or ``--robot-risk-scale``.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from riskplan.app.reproduce.risk_calibration import RISK_STUDY_SCALES, run_risk_study
from riskplan.errors import InvalidInputError

__all__ = ["ROBOT_RISK_FOR", "robot_risk_section", "robot_risk_stage"]

#: the study's sizes a named ``reproduce`` scale uses (docs/reproduce.md, "Stage robot-risk")
ROBOT_RISK_FOR = {"smoke": "smoke", "paper": "full"}


def _risk_key(label: str) -> str:
    """``results.json`` key of a risk of the study: ``eq9``, ``cloud_rho=<ρ>``, ``bodies_c=<c>``."""
    if label.startswith("eq9"):
        return "eq9"
    name, value = label.split(" ", 1)
    return f"{name}_{value.replace('ρ', 'rho')}"


def robot_risk_stage(
    out,
    scale_name: str,
    *,
    seed: int = 0,
    progress=None,
    backend: str = "serial",
    workers: int | None = None,
    robot_risk_scale: str | None = None,
) -> dict:
    """The ``robot-risk`` stage of ``riskplan reproduce``: the study into ``out/robot-risk``.

    Parameters
    ----------
    out : path
        The reproduction's output folder; the study's files go to ``out/robot-risk``
        (``risk_calibration.{json,png}`` and ``store/``, resumable).
    scale_name : str
        The reproduction's scale; its study sizes are :data:`ROBOT_RISK_FOR` (``smoke`` for
        ``smoke``, ``full`` for ``paper``, ``smoke`` otherwise) unless ``robot_risk_scale``
        names one of :data:`RISK_STUDY_SCALES`.
    seed, progress, backend, workers
        As in :func:`run_risk_study`.

    Returns
    -------
    dict
        What ``results.json`` holds under ``mdn.robot_risk``: per risk (keys ``eq9``,
        ``cloud_rho=<ρ>``, ``bodies_c=<c>``, listed in ``risks``) ``mae_band`` (mean absolute
        error on the items measured in [5 %, 95 %]), ``brier`` (over all executions),
        ``n_band``, ``n``, ``spearman`` (on the band items; ``None``: undefined), ``mae_all``,
        ``bias_band`` (mean signed error on the band items), ``brier_trajectories`` and
        ``label``; and ``scale``, ``sizes``, ``seed``, ``share_band``, ``figure``.
    """
    from riskplan.app.store import ResultStore

    name = robot_risk_scale or ROBOT_RISK_FOR.get(scale_name, "smoke")
    if name not in RISK_STUDY_SCALES:
        raise InvalidInputError(
            f"robot_risk_scale: expected one of {', '.join(RISK_STUDY_SCALES)}, got {name!r}"
        )
    sc = RISK_STUDY_SCALES[name]
    folder = Path(out) / "robot-risk"
    # the configuration of ``plan chest-risk-study``'s store: either continues the other's work
    store = ResultStore(
        folder / "store", {"study": "chest-risk", "scale": asdict(sc), "seed": int(seed)}
    )
    r = run_risk_study(
        folder, sc, store, seed=seed, progress=progress, backend=backend, workers=workers
    )
    measured = np.r_[r["measured"]["configurations"], r["measured"]["trajectories"]]
    band = (measured >= 0.05) & (measured <= 0.95)
    res: dict = {
        "scale": name,
        "sizes": asdict(sc),
        "seed": int(seed),
        "share_band": r["share_measured_5_95"],
        "figure": "robot-risk/risk_calibration.png",
        "risks": [],
    }
    for label, m in r["metrics"].items():
        key = _risk_key(label)
        pr = r["predicted"][label]
        p = np.r_[pr["configurations"], pr["trajectories"]]
        a = m["all"]
        res["risks"].append(key)
        res[key] = {
            "label": label,
            "mae_band": a["mae_mid"],
            "brier": a["brier"],
            "n_band": a["n_mid"],
            "n": a["n"],
            "spearman": a["spearman_mid"],
            "mae_all": a["mae_all"],
            "bias_band": float((p - measured)[band].mean()) if band.any() else None,
            "brier_trajectories": m["trajectories"]["brier"],
        }
    return json.loads(json.dumps(res))


def robot_risk_section(rep, out, r: dict) -> None:
    """The ``robot-risk`` stage in ``report.html``: the calibration plot and the table.

    ``rep``: the :class:`~riskplan.app.report.Report`; ``out``: the reproduction's folder;
    ``r``: ``results["mdn"]["robot_risk"]`` (:func:`robot_risk_stage`).
    """
    from riskplan.app.report import Report

    sec = rep.section("Chest: a risk the robot agrees with (robot-risk stage, beyond the paper)")
    sz = r["sizes"]
    Report.text(
        sec,
        f"Scale '{r['scale']}': {sz['configurations']} configurations and {sz['trajectories']} "
        f"straight ramps of {sz['steps']} configurations in the chest, each executed "
        f"{sz['executions']} times on the simulated robot (backbone + disks); "
        f"{100 * r['share_band']:.0f} % of the items measured between 5 % and 95 %. Each risk "
        "computed from the learned model beside the measured collision rate; eq. 9/10 is the "
        "paper's (and the reproduction's default). Goal: mean absolute error on the 5-95 % items "
        "at most 5 points.",
    )
    rep.image(
        sec,
        Path(out) / r["figure"],
        "Binned calibration: predicted risk against the robot's collision rate (diagonal: perfect)",
    )

    def pts(v):
        return "n/a" if v is None else f"{100 * v:.1f}"

    Report.table(
        sec,
        [
            "risk",
            "MAE, 5-95 % items [points]",
            "items in 5-95 %",
            "MAE, all [points]",
            "mean signed error, 5-95 % [points]",
            "Brier, all",
            "Brier, trajectories",
            "Spearman, 5-95 %",
            "goal met",
        ],
        [
            [
                r[k]["label"] + (" (two-fold, held out)" if k.startswith("logistic") else ""),
                pts(r[k]["mae_band"]),
                f"{r[k]['n_band']} of {r[k]['n']}",
                pts(r[k]["mae_all"]),
                pts(r[k]["bias_band"]),
                f"{r[k]['brier']:.3f}",
                f"{r[k]['brier_trajectories']:.3f}",
                "n/a" if r[k]["spearman"] is None else f"{r[k]['spearman']:.2f}",
                "n/a"
                if r[k]["mae_band"] is None
                else ("yes" if r[k]["mae_band"] <= 0.05 else "no"),
            ]
            for k in r["risks"]
        ],
        caption="Brier score over all executions; the rank correlation on the 5-95 % items",
    )
