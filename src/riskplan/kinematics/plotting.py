"""Figures of the MDN paper: Fig. 4 (test NLL vs number of components) and Fig. 5
(model samples vs ground-truth points). matplotlib and plotly are imported inside the
functions (optional ``viz`` extra)."""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_generator, check_counts
from riskplan.errors import require
from riskplan.robots.plotting import equal_axes_3d


def fig_nll_vs_components(result):
    """Fig. 4: test NLL per ``K``; collapsed ``K`` marked, recommended ``K`` highlighted.

    ``result``: a :class:`riskplan.kinematics.sweep.SweepResult`. Returns a matplotlib figure.
    """
    plt = require("matplotlib.pyplot", "viz")
    ks = np.array(result.components)
    nll = np.array(result.test_nll)
    collapsed = np.array([bool(e.collapsed) for e in result.entries])
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    ax.plot(ks, nll, "-o", color="tab:blue", label="test NLL")
    if collapsed.any():
        ax.plot(
            ks[collapsed], nll[collapsed], "x", color="tab:red", ms=10, mew=2, label="mode collapse"
        )
    i = int(np.flatnonzero(ks == result.recommended)[0])
    ax.plot(
        [ks[i]],
        [nll[i]],
        "o",
        ms=13,
        mfc="none",
        mec="tab:green",
        mew=2,
        label=f"recommended K={result.recommended}",
    )
    ax.set_xlabel("number of mixture components K")
    ax.set_ylabel("test NLL [nats/point, m]")
    ax.set_xticks(ks)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def _fig5_data(model, data, n_configs: int, n_samples: int, seed: int):
    check_counts({"n_configs": n_configs, "n_samples": n_samples}, 1)
    rng = as_generator(seed)
    idx = np.sort(rng.choice(data.n_configs, size=min(n_configs, data.n_configs), replace=False))
    gm = model.predict(data.displacements[idx])
    samples = gm.sample(n_samples, seed=seed).numpy()
    gts = []
    for i in idx:
        gt = data.points[i]
        if len(gt) > n_samples:
            gt = gt[rng.choice(len(gt), size=n_samples, replace=False)]
        gts.append(gt)
    return idx, samples, gts


def fig_samples_vs_truth(model, data, n_configs: int = 2, n_samples: int = 2000, seed: int = 0):
    """Fig. 5: red = samples of the predicted mixture, blue = ground-truth points, for
    ``n_configs`` random test configurations (3-D scatter, millimetres). Returns a matplotlib figure."""
    plt = require("matplotlib.pyplot", "viz")
    idx, samples, gts = _fig5_data(model, data, n_configs, n_samples, seed)
    fig = plt.figure(figsize=(5.0 * len(idx), 5.0))
    for j, i in enumerate(idx):
        ax = fig.add_subplot(1, len(idx), j + 1, projection="3d")
        g, s = gts[j] * 1e3, samples[j] * 1e3
        ax.scatter(g[:, 0], g[:, 1], g[:, 2], s=1, c="tab:blue", alpha=0.35, label="ground truth")
        ax.scatter(s[:, 0], s[:, 1], s[:, 2], s=1, c="tab:red", alpha=0.35, label="MDN samples")
        allp = np.concatenate([g, s])
        equal_axes_3d(ax, allp.mean(0), (allp.max(0) - allp.min(0)).max() / 2, "mm")
        disp = ", ".join(f"{v * 1e3:.1f}" for v in data.displacements[i])
        ax.set_title(f"config {i}: d = ({disp}) mm", fontsize=9)
        if j == 0:
            ax.legend(markerscale=6, fontsize=8, loc="upper left")
    fig.tight_layout()
    return fig


def plotly_samples_vs_truth(model, data, n_configs: int = 2, n_samples: int = 2000, seed: int = 0):
    """Interactive version of Fig. 5 (plotly figure, one 3-D scene per configuration)."""
    require("plotly", "viz")
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    idx, samples, gts = _fig5_data(model, data, n_configs, n_samples, seed)
    fig = make_subplots(
        rows=1,
        cols=len(idx),
        specs=[[{"type": "scene"}] * len(idx)],
        subplot_titles=[f"config {i}" for i in idx],
    )
    for j in range(len(idx)):
        for pts, name, color in (
            (gts[j], "ground truth", "royalblue"),
            (samples[j], "MDN samples", "crimson"),
        ):
            p = pts * 1e3
            fig.add_trace(
                go.Scatter3d(
                    x=p[:, 0],
                    y=p[:, 1],
                    z=p[:, 2],
                    mode="markers",
                    name=name,
                    marker=dict(size=1.5, color=color, opacity=0.5),
                    showlegend=j == 0,
                ),
                row=1,
                col=j + 1,
            )
    fig.update_scenes(
        aspectmode="data", xaxis_title="x [mm]", yaxis_title="y [mm]", zaxis_title="z [mm]"
    )
    fig.update_layout(title="MDN samples (red) vs ground-truth points (blue)", height=600)
    return fig
