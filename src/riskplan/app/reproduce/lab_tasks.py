"""Are the Kuntz lab's task configurations free on riskplan's robot model? (docs/robots.md,
"What the lab's task files mean").

Two measurements on the lab's collapse-segmentation data (Kuntz-Lab/Tendon_Robot_Learning,
``resources/collapse-segmentation/``):

* :func:`configuration_clearance`: the lab's backbone check (``VoxelBackboneValidityChecker``:
  the backbone polyline voxelised into the obstacle grid) and the clearance of the backbone to
  the nearest occupied cell, for start and goal of task files;
* :func:`tip_agreement`: the lab's recorded tips (``cheap-ik*.csv``: ``tip_x, tip_y, tip_z``,
  then the configuration) against riskplan's tips for the same configurations, also in the
  rotation- and mirror-invariant coordinates ``(sqrt(x^2 + y^2), z)``.

``python -m riskplan.app.reproduce.lab_tasks DIR`` prints both for the lab's folder ``DIR``
(``problem.toml``, ``tasks*/task-*.toml`` and ``cheap-ik*.csv``); robot and voxel environment
come from ``problem.toml``, the configurations from the task files.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["ConfigurationCheck", "configuration_clearance", "tip_agreement"]


@dataclass(frozen=True)
class ConfigurationCheck:
    """One configuration against the voxel obstacles.

    crosses: the backbone polyline (each step split in 4) meets an occupied cell.
    clearance: smallest distance (m) from a backbone point's cell centre to an occupied cell
        centre (0 inside one).
    """

    configuration: tuple[float, ...]
    crosses: bool
    clearance: float


def _occupancy(venv):
    from scipy.ndimage import distance_transform_edt

    grid = venv.load()
    occ = np.zeros((grid.dimension,) * 3, dtype=bool)
    occ[tuple(grid.occupied.T)] = True
    # distance of every cell centre to the nearest occupied cell centre (m)
    return grid, occ, distance_transform_edt(~occ, sampling=grid.spacing)


def configuration_clearance(
    robot, configurations, venv, *, _cache=None
) -> list[ConfigurationCheck]:
    """``(N, n_config)`` configurations of ``robot`` against the voxel file of ``venv``
    (a :class:`~riskplan.planning.problem_voxels.VoxelEnvironment`), robot frame -> voxel frame by
    ``venv.robot_to_voxel``. Returns one :class:`ConfigurationCheck` per configuration."""
    grid, occ, dist = _cache if _cache is not None else _occupancy(venv)
    out = []
    t = np.linspace(0.0, 1.0, 5)[:-1]
    for q in np.atleast_2d(np.asarray(configurations, dtype=np.float64)):
        tau, rot, ret = robot.split_configuration(q)
        P = robot.solve_tensions(tau, rotation=rot, retraction=ret).positions
        dense = np.vstack(
            [(P[:-1, None] + t[:, None] * (P[1:, None] - P[:-1, None])).reshape(-1, 3), P[-1:]]
        )
        idx = np.floor((venv.robot_to_voxel(dense) - grid.limits[:, 0]) / grid.spacing).astype(int)
        inside = np.all((idx >= 0) & (idx < grid.dimension), axis=1)
        hit = occ[tuple(idx[inside].T)]
        clear = dist[tuple(idx[inside].T)]
        out.append(
            ConfigurationCheck(
                tuple(float(v) for v in q),
                bool(hit.any()),
                float(clear.min()) if clear.size else float("inf"),
            )
        )
    return out


def tip_agreement(robot, csv_path) -> dict:
    """The lab's tips in ``csv_path`` against ``robot``'s tips (m).

    Returns ``{"n", "error" (n,), "invariant_error" (n,)}``: the tip distance, and the distance
    in ``(sqrt(x^2 + y^2), z)``. Rows with the robot at its home configuration (everything but
    1 mm retracted, tensions zero) are left out: every convention agrees there."""
    A = np.loadtxt(csv_path, delimiter=",", skiprows=1, ndmin=2)
    m = robot.n_tendons
    Q = A[:, 3:]
    keep = np.any(Q[:, :m] != 0.0, axis=1)
    A, Q = A[keep], Q[keep]
    tips = np.array(
        [robot.solve_tensions(q[:m], rotation=q[m], retraction=q[m + 1]).tip for q in Q]
    )
    lab = A[:, :3]
    inv = np.hypot(
        np.hypot(tips[:, 0], tips[:, 1]) - np.hypot(lab[:, 0], lab[:, 1]), tips[:, 2] - lab[:, 2]
    )
    return {"n": len(A), "error": np.linalg.norm(tips - lab, axis=1), "invariant_error": inv}


def lab_task_report(folder) -> list[str]:
    """The lines of ``riskplan study lab-tasks FOLDER``: the lab's task configurations of
    ``FOLDER/tasks*/task-*.toml`` against its voxel anatomy, and our tips against the tips of
    its ``cheap-ik*.csv`` files (docs/robots.md, "What the lab's task files mean")."""
    import tomllib

    from riskplan.planning.problem import load_problem

    root = Path(folder)
    files = sorted(root.glob("tasks*/task-*.toml"))
    # the task files name the mesh beside them and some name absolute paths on the lab's
    # machines: the robot and the voxel environment come from the folder's problem.toml (the
    # same robot and frames), the configurations from each task file
    problem = load_problem(root / "problem.toml")
    configs, seen = [], set()
    for f in files:
        p = tomllib.loads(f.read_text())["problem"]
        for e in ("start", "goal"):
            c = np.r_[p[e], p[f"{e}_rotation"], p[f"{e}_retraction"]]
            key = tuple(np.round(c, 9))
            if key not in seen:
                seen.add(key)
                configs.append(c)
    robot, venv = problem.robot, problem.voxel_environment
    checks = configuration_clearance(robot, configs, venv)
    r = robot.params.collision_radius
    n = len(checks)
    lines = [f"{len(files)} task files, {n} distinct start/goal configurations"]
    lines.append(f"backbone crosses the voxel obstacles: {sum(c.crosses for c in checks)} / {n}")
    lines.append(
        f"clearance >= radius {r * 1e3:g} mm: {sum(c.clearance >= r for c in checks)} / {n}"
    )
    for csv in sorted(root.glob("cheap-ik*.csv")):
        a = tip_agreement(robot, csv)
        e, i = a["error"] * 1e3, a["invariant_error"] * 1e3
        lines.append(
            f"{csv.name}: n={a['n']} tip error median {np.median(e):.1f} mm "
            f"({e.min():.1f}-{e.max():.1f}); (rho, z) error median {np.median(i):.1f} mm"
        )
    return lines
