"""Frames and animations of the tissue scenarios (matplotlib; imported inside functions).

``draw_frame`` draws one state: deformed mesh, obstacles, goal, and the robot (needle) or
target and manipulators (manipulation) with the path so far. ``save_frames`` writes PNG
frames and ``save_gif`` an animated GIF (Pillow) of a list of states.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from riskplan.errors import require

__all__ = ["draw_frame", "figure_for", "frame_indices", "save_frames", "save_gif"]


def _triangles(sim, state):
    return sim.mesh_data(state.n_elements).mesh.triangles


def _scene_size(sim) -> float:
    """The scene's largest extent (1 for the paper's scenes): the scale of margins and
    arrows, so a scenario file's scene in millimetres or metres draws alike."""
    cfg = sim.config
    if sim.name == "needle":
        return max(float(cfg.width), float(cfg.height))
    return float((cfg.outline.max(0) - cfg.outline.min(0)).max())


def _limits(sim):
    cfg = sim.config
    if sim.name == "needle":
        m = 0.05 * _scene_size(sim)
        (lo_x, lo_y), (hi_x, hi_y) = cfg.bounds
        return (lo_x - m, hi_x + m), (lo_y - m, hi_y + m)
    pts = np.concatenate([cfg.outline, cfg.obstacle, cfg.goal_polygon])
    lo, hi = pts.min(0), pts.max(0)
    pad = 0.25 * float((hi - lo).max())
    return (lo[0] - pad, hi[0] + pad), (lo[1] - pad, hi[1] + pad)


def figure_for(sim, size: float = 4.8):
    """A square figure and axes sized for ``sim``'s scene.

    Parameters
    ----------
    sim : Simulator
        A 2-D tissue scenario.
    size : float
        Figure side (inches).

    Returns
    -------
    fig : matplotlib.figure.Figure
        The figure.
    ax : matplotlib.axes.Axes
        Its axes.
    """
    plt = require("matplotlib.pyplot", "viz")
    fig, ax = plt.subplots(figsize=(size, size))
    return fig, ax


def draw_frame(
    ax, sim, states, k: int | None = None, *, title: str | None = None, show_undeformed: bool = True
):
    """Draw ``states[k]`` (default: the last) of scenario ``sim`` on ``ax``.

    Shows the deformed mesh (grey), the undeformed outline (dashed), obstacles (dark
    grey), the goal (green), and for the needle the robot (red arrow) and its path, for
    the manipulation scenario the target (blue) and its path, the manipulators (red) and
    the traces of the manipulator positions.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    sim : Simulator
    states : sequence of SimState
        A rollout ``[y_0, ..., y_T]``.
    k : int, optional
        The state drawn; the paths run up to it.
    title : str, optional
    show_undeformed : bool
        Draw the undeformed outline.

    Returns
    -------
    matplotlib.axes.Axes
        ``ax``.
    """
    from matplotlib.patches import Polygon

    k = len(states) - 1 if k is None else k
    st = states[k]
    ax.clear()
    tri = _triangles(sim, st)
    nodes = sim.deformed_nodes(st)
    ax.triplot(nodes[:, 0], nodes[:, 1], tri, color="0.6", lw=0.5)
    if show_undeformed:
        ref = sim.config.corners if sim.name == "needle" else sim.config.outline
        ax.add_patch(Polygon(ref, closed=True, fill=False, ls="--", ec="0.35", lw=0.8))
    for poly in sim.obstacles(st):
        ax.add_patch(Polygon(poly, closed=True, fc="0.3", ec="0.1", alpha=0.8))
    ax.add_patch(Polygon(sim.goal(st), closed=True, fc="tab:green", ec="darkgreen", alpha=0.5))
    if sim.name == "needle":
        path = sim.path(states[: k + 1])
        ax.plot(path[:, 0], path[:, 1], "-", color="tab:red", lw=1.5)
        x, y, th = st.pose
        ax.plot([x], [y], "o", color="tab:red", ms=5)
        size = _scene_size(sim)
        ax.arrow(
            x,
            y,
            0.05 * size * np.cos(th),
            0.05 * size * np.sin(th),
            width=0.004 * size,
            color="tab:red",
        )
    else:
        path = sim.path(states[: k + 1])
        ax.plot(path[:, 0], path[:, 1], "-", color="tab:blue", lw=1.5)
        tgt = sim.target(st)
        ax.plot([tgt[0]], [tgt[1]], "o", color="tab:blue", ms=6)
        bpts = sim.boundary_points(st)
        ax.plot(bpts[:, 0], bpts[:, 1], ".", color="k", ms=4)
        traces = np.array([sim.manipulator_positions(s) for s in states[: k + 1]])  # (k+1, 3, 2)
        for j in range(traces.shape[1]):
            ax.plot(traces[:, j, 0], traces[:, j, 1], "-", color="tab:red", lw=0.8, alpha=0.7)
        mp = traces[-1]
        ax.plot(mp[:, 0], mp[:, 1], "o", color="tab:red", ms=6)
        if np.any(st.forces):
            size = _scene_size(sim)
            scale = 0.1 * size / max(sim.config.f_max, 1e-12)
            for p, f in zip(mp, st.forces):
                ax.arrow(
                    p[0],
                    p[1],
                    scale * f[0],
                    scale * f[1],
                    width=0.004 * size,
                    color="tab:red",
                    alpha=0.8,
                )
    xl, yl = _limits(sim)
    ax.set_xlim(*xl)
    ax.set_ylim(*yl)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title if title is not None else f"{sim.name}: step {st.t}", fontsize=10)
    return ax


def frame_indices(n_states: int, max_frames: int) -> list[int]:
    """At most ``max_frames`` evenly spaced state indices, always including the last.

    Parameters
    ----------
    n_states : int
    max_frames : int

    Returns
    -------
    list of int
    """
    if n_states <= max_frames:
        return list(range(n_states))
    idx = np.unique(np.linspace(0, n_states - 1, max_frames).round().astype(int))
    return idx.tolist()


def save_frames(
    sim,
    states,
    out_dir,
    *,
    prefix: str = "frame",
    max_frames: int = 60,
    dpi: int = 90,
    on_frame=None,
) -> list[Path]:
    """Write PNG frames ``out_dir/{prefix}_{k:04d}.png`` of (at most ``max_frames``) states.

    Parameters
    ----------
    sim : Simulator
    states : sequence of SimState
    out_dir : str or path
    prefix : str
    max_frames : int
    dpi : int
    on_frame : callable, optional
        ``on_frame(k)`` after state ``k``'s frame is written (progress display).

    Returns
    -------
    list of pathlib.Path
    """
    plt = require("matplotlib.pyplot", "viz")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fig, ax = figure_for(sim)
    paths = []
    try:
        for k in frame_indices(len(states), max_frames):
            draw_frame(ax, sim, states, k)
            p = out / f"{prefix}_{k:04d}.png"
            fig.savefig(p, dpi=dpi)
            paths.append(p)
            if on_frame is not None:
                on_frame(k)
    finally:
        plt.close(fig)
    return paths


def save_gif(sim, states, path, *, max_frames: int = 60, fps: int = 8, dpi: int = 70) -> Path:
    """Animated GIF of the states (matplotlib ``PillowWriter``), written atomically.

    Parameters
    ----------
    sim : Simulator
    states : sequence of SimState
    path : str or path
    max_frames : int
    fps : int
    dpi : int

    Returns
    -------
    pathlib.Path
    """
    plt = require("matplotlib.pyplot", "viz")
    from matplotlib.animation import PillowWriter

    from riskplan.io import atomic_path

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = figure_for(sim)
    writer = PillowWriter(fps=fps)
    try:
        with atomic_path(
            path, suffix=".gif"
        ) as tmp:  # PillowWriter picks the format from the suffix
            with writer.saving(fig, str(tmp), dpi=dpi):
                for k in frame_indices(len(states), max_frames):
                    draw_frame(ax, sim, states, k)
                    writer.grab_frame()
    finally:
        plt.close(fig)
    return path
