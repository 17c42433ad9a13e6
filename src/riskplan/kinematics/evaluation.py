"""Evaluating a trained MDN against held-out point clouds (MDN paper, section IV).

Three measures, each per configuration and then averaged over configurations:

* **Test NLL** — mean ``-log p(x | d)`` over all ground-truth points (nats per point,
  positions in metres; the quantity of the paper's Fig. 4).
* **Chamfer distance** — symmetric mean nearest-neighbour distance between ``n`` points
  sampled from the model and ``n`` ground-truth points:
  ``CD(A, B) = 1/2 (mean_a min_b |a - b| + mean_b min_a |a - b|)`` [m].
* **HDR calibration** — the level-``alpha`` highest-density region of a density ``p`` is
  ``R_alpha = {x : p(x) >= q_alpha}`` with ``P(X in R_alpha) = alpha``; ``q_alpha`` is the
  ``(1 - alpha)`` quantile of ``p(X)``, ``X ~ p``, estimated from samples of the mixture.
  A calibrated model puts a fraction ``alpha`` of the ground-truth points inside ``R_alpha``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from riskplan._validation import as_generator, check_count
from riskplan.errors import InvalidInputError
from riskplan.kinematics.data import PointCloudData, check_compatible
from riskplan.kinematics.mdn import MDNModel
from riskplan.kinematics.torch_mixture import GaussianMixture
from riskplan.parallel import spawn_seeds

DEFAULT_LEVELS = (0.5, 0.9, 0.95)


def chamfer_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Chamfer distance between point sets ``a (n, 3)`` and ``b (k, 3)`` (mean NN distance, averaged both ways)."""
    from scipy.spatial import cKDTree

    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1] or len(a) == 0 or len(b) == 0:
        raise InvalidInputError(
            f"chamfer_distance: expected non-empty (n, d) and (k, d) point sets, got {a.shape} and {b.shape}"
        )
    dab = cKDTree(b).query(a, k=1)[0]
    dba = cKDTree(a).query(b, k=1)[0]
    return 0.5 * (float(dab.mean()) + float(dba.mean()))


def hdr_thresholds(
    mixture: GaussianMixture, levels=DEFAULT_LEVELS, n_samples: int = 4096, seed=0
) -> torch.Tensor:
    """Log-density thresholds ``log q_alpha`` of the level-``alpha`` HDRs, shape ``(..., L)``.

    ``q_alpha`` is the empirical ``(1 - alpha)`` quantile of ``log p(X)`` over ``n_samples``
    draws ``X ~ mixture`` (the HDR definition of Hyndman, 1996, estimated by sampling).
    """
    levels = _check_levels(levels)
    x = mixture.sample(n_samples, seed=seed)
    lp = mixture.log_prob(x)  # (..., n)
    q = torch.as_tensor([1.0 - a for a in levels], dtype=lp.dtype)
    return torch.quantile(lp, q, dim=-1).movedim(0, -1)


def hdr_coverage(
    mixture: GaussianMixture, points, levels=DEFAULT_LEVELS, n_samples: int = 4096, seed=0
) -> torch.Tensor:
    """Fraction of ``points (..., N, 3)`` inside each level-``alpha`` HDR of ``mixture``; ``(..., L)``."""
    thr = hdr_thresholds(mixture, levels, n_samples, seed)
    lp = mixture.log_prob(points)
    return (lp.unsqueeze(-1) >= thr.unsqueeze(-2)).to(lp.dtype).mean(-2)


def _check_levels(levels) -> tuple[float, ...]:
    levels = tuple(float(a) for a in levels)
    if not levels or any(not 0.0 < a < 1.0 for a in levels):
        raise InvalidInputError(f"levels: expected values in (0, 1), got {levels}")
    return levels


@dataclass
class Evaluation:
    """Results of :func:`evaluate` (means over test configurations, and per-configuration arrays)."""

    nll: float
    chamfer: float
    calibration: dict[float, float]
    nll_per_config: np.ndarray
    chamfer_per_config: np.ndarray
    coverage_per_config: np.ndarray  # (C, L)
    levels: tuple[float, ...]
    n_configs: int
    n_points: int

    def to_json(self) -> dict:
        return {
            "test_nll": self.nll,
            "chamfer_m": self.chamfer,
            "chamfer_mm": self.chamfer * 1e3,
            "calibration": {f"{a:g}": c for a, c in self.calibration.items()},
            "calibration_error": {f"{a:g}": c - a for a, c in self.calibration.items()},
            "calibration_config_std": {
                f"{a:g}": float(s) for a, s in zip(self.levels, self.coverage_per_config.std(0))
            },
            "n_configs": self.n_configs,
            "n_points_per_config": self.n_points,
            "nll_units": "nats per point, positions in metres",
        }


def nll_per_config(model: MDNModel, data: PointCloudData, chunk: int = 64) -> np.ndarray:
    """Per-configuration mean NLL of all ground-truth points, ``(C,)`` (float64)."""
    out = np.empty(data.n_configs)
    for s in range(0, data.n_configs, chunk):
        gm = model.predict(data.displacements[s : s + chunk])
        lp = gm.log_prob(torch.from_numpy(data.points[s : s + chunk].astype(np.float64)))
        out[s : s + chunk] = -lp.mean(-1).numpy()
    return out


def evaluate(
    model: MDNModel,
    data: PointCloudData,
    *,
    levels=DEFAULT_LEVELS,
    n_samples: int = 4096,
    chamfer_points: int = 2048,
    seed: int = 0,
    max_configs: int | None = None,
) -> Evaluation:
    """Test NLL, Chamfer distance and HDR calibration of ``model`` on ``data``.

    ``n_samples`` mixture draws per configuration estimate the HDR thresholds;
    Chamfer uses ``min(chamfer_points, N)`` model samples against as many ground-truth
    points (a random subset). ``max_configs`` evaluates a random subset of configurations.
    Raises :class:`DataFormatError` if ``data`` belongs to another robot and
    :class:`InvalidInputError` for counts below 1.
    """
    levels = _check_levels(levels)
    for name, v in (("n_samples", n_samples), ("chamfer_points", chamfer_points)):
        check_count(v, name, 1)
    if max_configs is not None:
        check_count(max_configs, "max_configs", 1)
    check_compatible(
        {
            "robot_toml": model.robot_toml,
            "n_tendons": model.n_tendons,
            "robot_name": model.robot_name,
        },
        data,
    )
    rng = as_generator(seed)
    if max_configs is not None and max_configs < data.n_configs:
        data = data.subset(np.sort(rng.choice(data.n_configs, size=max_configs, replace=False)))
    C, N = data.n_configs, data.n_points
    nll = nll_per_config(model, data)
    cham = np.empty(C)
    cov = np.empty((C, len(levels)))
    n_ch = min(chamfer_points, N)
    chunk = 32
    # per chunk, one stream for the HDR coverage and one for the Chamfer samples
    chunk_seeds = spawn_seeds(seed, 2 * (-(-C // chunk)))
    for s in range(0, C, chunk):
        gm = model.predict(data.displacements[s : s + chunk])
        pts = torch.from_numpy(data.points[s : s + chunk].astype(np.float64))
        cov[s : s + chunk] = hdr_coverage(
            gm, pts, levels, n_samples, seed=chunk_seeds[2 * (s // chunk)]
        ).numpy()
        samples = gm.sample(n_ch, seed=chunk_seeds[2 * (s // chunk) + 1]).numpy()
        for i in range(gm.batch_shape[0]):
            gt = data.points[s + i]
            if n_ch < N:
                gt = gt[rng.choice(N, size=n_ch, replace=False)]
            cham[s + i] = chamfer_distance(samples[i], gt)
    calib = {a: float(c) for a, c in zip(levels, cov.mean(0))}
    return Evaluation(float(nll.mean()), float(cham.mean()), calib, nll, cham, cov, levels, C, N)


def component_weight_stats(model: MDNModel, displacements: np.ndarray) -> dict:
    """Per-component weight statistics over configurations ``(C, m)``: mean, max, 99th percentile."""
    w = model.predict(displacements).weights.numpy()  # (C, K)
    return {"mean": w.mean(0), "max": w.max(0), "p99": np.quantile(w, 0.99, axis=0)}


def mode_collapse(weight_p99: np.ndarray, threshold: float) -> list[int]:
    """Components whose weight stays below ``threshold`` on 99 % of the configurations.

    Such a component is practically never used (the paper's "mode collapse": weights
    arbitrarily close to zero); the model could have been trained with fewer components.
    """
    if not (0.0 < threshold < 1.0 and math.isfinite(threshold)):
        raise InvalidInputError(f"threshold: expected in (0, 1), got {threshold}")
    return [int(k) for k in np.flatnonzero(np.asarray(weight_p99) < threshold)]


def evaluate_for_report(model, test_data, seed: int):
    """The Fig. 5 evaluation the demo and ``reproduce`` report: 2048 samples and 1024 Chamfer
    points per configuration, on at most 60 test configurations."""
    return evaluate(
        model,
        test_data,
        n_samples=2048,
        chamfer_points=1024,
        seed=seed,
        max_configs=min(test_data.n_configs, 60),
    )
