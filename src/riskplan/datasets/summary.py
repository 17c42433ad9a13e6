"""Summary of a data-set file (``riskplan dataset info``): robot, protocol, configurations
done, and the spread of tips, cloud centroids and points."""

from __future__ import annotations

import numpy as np

from riskplan.datasets.storage import load_dataset
from riskplan.errors import RiskplanError

__all__ = ["over_max_tension", "summarize"]


def over_max_tension(tensions, tension_limits, done=None) -> dict:
    """Arrivals whose tendon tensions exceed ``max_tension``: counts and indices.

    An arrival ``(c, s)`` is over the limit when ``tensions[c, s, j] > tension_limits[j]
    (1 + 1e-9)`` for some tendon ``j``.

    Parameters
    ----------
    tensions : array_like, shape (C, S, m)
        Arrival tensions [N] of ``C`` targets, ``S`` arrivals each, ``m`` tendons.
    tension_limits : array_like, shape (m,)
        Each tendon's ``max_tension`` [N].
    done : array_like of bool, shape (C,), optional
        The targets to count (default all).

    Returns
    -------
    dict
        ``arrivals`` (n, the arrivals over a limit), ``of`` (N, the arrivals counted),
        ``fraction`` (n / N, 0 when N is 0), ``targets`` (ascending indices of the targets with
        at least one such arrival) and ``per_tendon`` (per tendon ``j``, the arrivals over its
        limit).
    """
    tau = np.asarray(tensions, dtype=np.float64)
    C = tau.shape[0]
    idx = np.arange(C) if done is None else np.flatnonzero(np.asarray(done, dtype=bool))
    over = tau[idx] > np.asarray(tension_limits, dtype=np.float64) * (1 + 1e-9)  # (c, S, m)
    arrivals = over.any(-1)  # (c, S)
    total = int(arrivals.size)
    return {
        "arrivals": int(arrivals.sum()),
        "of": total,
        "fraction": float(arrivals.sum() / total) if total else 0.0,
        "targets": [int(i) for i in idx[arrivals.any(-1)]],
        "per_tendon": over.sum(axis=(0, 1)).astype(int).tolist(),
    }


def summarize(path) -> dict:
    """Summary of a data-set file: robot, protocol, configurations done, cloud and tip spread.

    Parameters
    ----------
    path : str or os.PathLike
        The data-set file.

    Returns
    -------
    dict
        The summary ``riskplan dataset info`` prints.
    """
    ds = load_dataset(path)
    done = ds.done
    summary = {
        "file": str(path),
        "robot": ds.metadata.get("robot_name"),
        "split": ds.metadata.get("split"),
        "seed": ds.metadata.get("seed"),
        "riskplan_version": ds.metadata.get("riskplan_version"),
        "created": ds.metadata.get("created"),
        "complete": ds.complete,
        "protocol": {k: v for k, v in ds.metadata["protocol"].items() if k != "cameras"},
        "n_cameras": len(ds.metadata["protocol"].get("cameras", [])),
        "configs_done": int(done.sum()),
        "configs_total": ds.n_configs,
        "points_shape": list(ds.points.shape),
    }
    if done.any():
        tips = ds.tips[done]
        spread = ds.tip_spread()[done]
        pts = ds.points[done].astype(np.float64)
        cen = pts.mean(axis=2)  # (C, S, 3) cloud centroids: their spread over the starts
        cen_rms = np.sqrt(((cen - cen.mean(axis=1, keepdims=True)) ** 2).sum(-1).mean(-1))
        summary.update(
            tip_spread_mm={
                "mean": float(spread.mean() * 1e3),
                "median": float(np.median(spread) * 1e3),
                "max": float(spread.max() * 1e3),
            },
            tip_range_m={
                "min": tips.reshape(-1, 3).min(0).tolist(),
                "max": tips.reshape(-1, 3).max(0).tolist(),
            },
            centroid_spread_mm={
                "mean": float(cen_rms.mean() * 1e3),
                "max": float(cen_rms.max() * 1e3),
            },
            bbox_m={
                "min": pts.reshape(-1, 3).min(0).tolist(),
                "max": pts.reshape(-1, 3).max(0).tolist(),
            },
        )
        try:
            over = over_max_tension(ds.tensions, ds.robot.tension_limits, done)
            summary["arrivals_over_max_tension"] = over["fraction"]
            summary["arrivals_over_max_tension_count"] = f"{over['arrivals']} of {over['of']}"
            summary["arrivals_over_max_tension_per_tendon"] = over["per_tendon"]
            summary["targets_over_max_tension"] = over["targets"]
        except RiskplanError as exc:
            # a robot file this version cannot rebuild must not stop the summary
            summary["arrivals_over_max_tension"] = f"unknown ({exc})"
    return summary
