"""Demo stage "robot": the simulated robot, its cameras and the small data sets (MDN paper Sec. III).

Generates the ``small`` preset (train and test) into ``ctx["out"]/data/`` and sets
``ctx["robot"]``, ``ctx["train_path"]``, ``ctx["test_path"]`` for the later stages. The
report shows robot shapes, one target's clouds (one start vs all starts, the paper's Fig. 3),
the tip spread per target, and what each camera sees.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from riskplan.app.report import Report

log = logging.getLogger(__name__)

PRESET = "small"
SHAPE_CONFIGS = (
    (0.0, 0.0, 0.0, 0.0),
    (0.03, 0.0, 0.0, 0.0),
    (0.0, 0.03, 0.0, 0.0),
    (0.0, 0.0, 0.0, 0.03),
    (0.02, 0.0, 0.0, 0.03),
)


def _disk_rings(shape, robot, n=40):
    """Circles of the separator disks ``(k, n, 3)`` of one shape (base frame)."""
    from riskplan.robots.geometry import interpolate_frames

    s_d = np.asarray(robot.params.disks.positions)
    P, R = interpolate_frames(shape.s, shape.positions, shape.rotations, s_d)
    a = np.linspace(0, 2 * np.pi, n)
    circ = robot.params.disks.radius * np.stack([np.cos(a), np.sin(a), 0 * a], -1)
    return P[:, None, :] + circ @ np.swapaxes(R, -1, -2)


def fig_shapes(robot, configs):
    import matplotlib.pyplot as plt

    shapes = robot.solve_displacements(np.asarray(configs, dtype=float))
    fig = plt.figure(figsize=(6.5, 5.5))
    ax = fig.add_subplot(projection="3d")
    for j, d in enumerate(configs):
        sh = shapes[j]
        P = sh.positions
        ax.plot(
            P[:, 0],
            P[:, 1],
            P[:, 2],
            color=f"C{j}",
            lw=2,
            label=f"d = {tuple(round(x, 3) for x in d)}",
        )
        for ring in _disk_rings(sh, robot):
            ax.plot(ring[:, 0], ring[:, 1], ring[:, 2], color=f"C{j}", lw=0.8)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_box_aspect((1, 1, 1))
    lim = 0.12
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_zlim(0, 0.22)
    ax.legend(fontsize=7, loc="upper left")
    return fig


def fig_clouds(points, tips, title: str):
    """Fig. 3 analogue: one cloud, all starts' clouds of the same target, and a zoom on the tip.

    ``points (S, P, 3)``, ``tips (S, 3)`` of one target (base frame, m).
    """
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(14, 4.8))
    allp = points.reshape(-1, 3)
    c = 0.5 * (allp.min(0) + allp.max(0))
    h = 0.5 * (allp.max(0) - allp.min(0)).max()
    for k, (pts, ttl) in enumerate(
        ((points[:1], "one start"), (points, f"all {len(points)} starts"))
    ):
        ax = fig.add_subplot(1, 3, k + 1, projection="3d")
        for j, cloud in enumerate(pts):
            ax.scatter(cloud[:, 0], cloud[:, 1], cloud[:, 2], s=1.5, color=f"C{j}", alpha=0.7)
        ax.scatter(
            tips[: len(pts), 0],
            tips[: len(pts), 1],
            tips[: len(pts), 2],
            color="k",
            marker="x",
            s=20,
        )
        ax.set_title(f"{ttl}", fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        ax.set_xlim(c[0] - h, c[0] + h)
        ax.set_ylim(c[1] - h, c[1] + h)
        ax.set_zlim(c[2] - h, c[2] + h)
    # zoom: points within 15 mm of the mean tip, seen from above (base x-y plane)
    ax = fig.add_subplot(1, 3, 3)
    mt = tips.mean(0)
    for j, cloud in enumerate(points):
        near = cloud[np.linalg.norm(cloud - mt, axis=1) < 0.015]
        ax.scatter(
            (near[:, 0] - mt[0]) * 1e3, (near[:, 1] - mt[1]) * 1e3, s=4, color=f"C{j}", alpha=0.7
        )
    ax.scatter(
        (tips[:, 0] - mt[0]) * 1e3,
        (tips[:, 1] - mt[1]) * 1e3,
        color="k",
        marker="x",
        s=30,
        label="true tips",
    )
    ax.set_aspect("equal")
    ax.set_xlabel("x - mean tip x [mm]")
    ax.set_ylabel("y - mean tip y [mm]")
    ax.set_title("near the tip (top view), one colour per start", fontsize=10)
    ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.subplots_adjust(wspace=0.35)
    return fig


def fig_camera_views(robot, protocol, displacements):
    """Depth images of both cameras and the merged cloud for one configuration."""
    import matplotlib.pyplot as plt

    from riskplan.robots.cameras import depth_image, render
    from riskplan.robots.geometry import BodyGeometry, sample_surface

    shape = robot.solve_displacements(np.asarray(displacements, dtype=float))
    body = BodyGeometry.from_params(robot.params, spacing=protocol.surface_spacing)
    pts, nrm = sample_surface(shape.s, shape.positions, shape.rotations, body)
    cams = protocol.camera_objects()
    fig = plt.figure(figsize=(13, 4.2))
    for k, cam in enumerate(cams):
        ax = fig.add_subplot(1, len(cams) + 1, k + 1)
        img = depth_image(pts, nrm, cam, seed=k)
        rows, cols = np.nonzero(np.isfinite(img))
        r0, r1 = max(rows.min() - 10, 0), min(rows.max() + 10, cam.height)
        c0, c1 = max(cols.min() - 10, 0), min(cols.max() + 10, cam.width)
        im = ax.imshow(img[r0:r1, c0:c1], cmap="viridis", extent=(c0, c1, r1, r0))
        fig.colorbar(im, ax=ax, label="depth [m]", shrink=0.8)
        ax.set_title(
            f"camera {k + 1} at {tuple(round(v, 2) for v in cam.position)} ({int(np.isfinite(img).sum())} px)"
        )
        ax.set_xlabel("column [px]")
        ax.set_ylabel("row [px]")
    ax = fig.add_subplot(1, len(cams) + 1, len(cams) + 1, projection="3d")
    for k, cam in enumerate(cams):
        c, _ = render(pts, nrm, cam, seed=k)
        ax.scatter(c[:, 0], c[:, 1], c[:, 2], s=0.5, color=f"C{k}", label=f"camera {k + 1}")
    ax.set_title("merged cloud (base frame)")
    ax.legend(fontsize=7)
    return fig


def run(report: Report, ctx: dict, *, seed: int, workers: int | None) -> None:
    from riskplan.datasets import PRESETS, generate_dataset, load_dataset
    from riskplan.robots import load_robot

    out = Path(ctx["out"])
    robot = ctx.get("robot") or load_robot("paper")
    protocol = PRESETS[PRESET]
    data = out / "data"
    t0 = time.perf_counter()
    paths = {}
    for split in ("train", "test"):
        paths[split] = generate_dataset(
            robot, PRESET, data / f"{PRESET}_{split}.h5", split=split, seed=seed, workers=workers
        )
    t_gen = time.perf_counter() - t0
    ctx["robot"] = robot
    ctx["train_path"], ctx["test_path"] = paths["train"], paths["test"]

    sec = report.section("Robot, simulated cameras and data sets (MDN paper Sec. III)")
    Report.text(
        sec,
        f"Robot '{robot.name}': {robot.n_tendons} tendons, displacement limits "
        f"{robot.displacement_limits[0].tolist()} m. Data sets by the paper's protocol (preset '{PRESET}'): "
        f"{protocol.n_train} training and {protocol.n_test} test targets on a {protocol.grid_levels}-level grid, "
        f"{protocol.n_starts} random starts each, straight path to the target through the hysteresis model, "
        f"two depth cameras on opposite sides, {protocol.n_points} points per cloud. Generated in {t_gen:.1f} s "
        f"(seed {seed}).",
    )
    report.figure(
        sec,
        fig_shapes(robot, SHAPE_CONFIGS),
        "robot_shapes",
        "Robot shapes (backbone and separator disks) for a few tendon displacements (nominal, no hysteresis).",
    )

    train = load_dataset(paths["train"])
    spread = train.tip_spread()
    i = int(
        np.argsort(spread)[len(spread) // 2 + len(spread) // 4]
    )  # a target with above-median spread
    report.figure(
        sec,
        fig_clouds(
            train.points[i], train.tips[i], f"d = {np.round(train.displacements[i], 4).tolist()}"
        ),
        "robot_clouds",
        "One target's point clouds (the paper's Fig. 3): one start (left) and all starts "
        "concatenated (right); crosses mark the true tips. The spread comes from the path-dependent transmission.",
    )
    report.figure(
        sec,
        fig_camera_views(robot, protocol, train.displacements[i]),
        "robot_cameras",
        "What each camera sees (depth images, cropped) and the merged cloud before downsampling.",
    )

    order = np.argsort(spread)[::-1]
    rows = [
        [
            int(k),
            str(np.round(train.displacements[k] * 1e3, 1).tolist()),
            float(spread[k] * 1e3),
            float(np.linalg.norm(train.tips[k] - train.tips[k].mean(0), axis=1).max() * 1e3),
        ]
        for k in order[:8]
    ]
    Report.table(
        sec,
        ["target", "displacements [mm]", "tip spread RMS [mm]", "max tip deviation [mm]"],
        rows,
        caption="Targets with the largest tip spread over their starts (training split)",
    )
    test = load_dataset(paths["test"])
    Report.table(
        sec,
        ["split", "targets", "clouds", "points/cloud", "tip spread mean [mm]", "median", "max"],
        [
            [
                name,
                ds.n_configs,
                ds.n_configs * ds.n_starts,
                ds.n_points,
                float(ds.tip_spread().mean() * 1e3),
                float(np.median(ds.tip_spread()) * 1e3),
                float(ds.tip_spread().max() * 1e3),
            ]
            for name, ds in (("train", train), ("test", test))
        ],
        caption="Data-set shapes and tip spread per target",
    )
