"""Matplotlib view of robot shapes (imported lazily; plotting helper, not library core)."""

from __future__ import annotations

import numpy as np


def equal_axes_3d(ax, center, half: float, unit: str) -> None:
    """Give the 3-D axes ``ax`` the cube ``center ± half`` (equal scales, so shapes are not
    distorted) and ``x/y/z [unit]`` labels."""
    for k, axis in enumerate("xyz"):
        getattr(ax, f"set_{axis}lim")(center[k] - half, center[k] + half)
        getattr(ax, f"set_{axis}label")(f"{axis} [{unit}]")


def plot_shape(
    shapes, robot=None, *, ax=None, title: str | None = None, color="C0", alpha: float = 1.0
):
    """Draw backbone curve(s) in 3-D and, with ``robot``, the separator disks as circles.

    ``shapes``: a :class:`~riskplan.robots.RodShape` (single or batched). Returns the figure.
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig = plt.figure(figsize=(5.5, 5.5))
        ax = fig.add_subplot(projection="3d")
    else:
        fig = ax.figure
    P = shapes.positions.reshape(-1, shapes.positions.shape[-2], 3)
    Rs = shapes.rotations.reshape(-1, shapes.positions.shape[-2], 3, 3)
    s = shapes.s
    phi = np.linspace(0, 2 * np.pi, 33)
    for b in range(P.shape[0]):
        ax.plot(P[b, :, 0], P[b, :, 1], P[b, :, 2], color=color, lw=2, alpha=alpha)
        if robot is not None:
            d = robot.params.disks
            for sd in d.positions:
                # interpolate the frame at the disk's arc length (nearest station's rotation)
                k = int(np.clip(np.searchsorted(s, sd), 1, len(s) - 1))
                w = (sd - s[k - 1]) / (s[k] - s[k - 1])
                c = (1 - w) * P[b, k - 1] + w * P[b, k]
                R = Rs[b, k if w > 0.5 else k - 1]
                circ = c + d.radius * (
                    np.cos(phi)[:, None] * R[:, 0] + np.sin(phi)[:, None] * R[:, 1]
                )
                ax.plot(circ[:, 0], circ[:, 1], circ[:, 2], color="0.4", lw=1, alpha=alpha)
    pts = P.reshape(-1, 3)
    ctr = 0.5 * (pts.max(0) + pts.min(0))
    half = max(0.5 * float((pts.max(0) - pts.min(0)).max()), 0.02) + 0.01
    equal_axes_3d(ax, ctr, half, "m")
    if title:
        ax.set_title(title)
    return fig
