"""Reading point-cloud data sets for training and evaluating the MDN.

The HDF5 schema is written by :mod:`riskplan.datasets` (attributes ``format``,
``format_version``, ``robot_toml``, ``robot_name``; data sets ``displacements (C, m)``,
``points (C, S, P, 3)``, ``done (C,)``). This module reads only what the kinematics
model needs, validates it before any training starts, and fingerprints the content
so a saved model records exactly which data it was trained on.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from riskplan.errors import DataFormatError

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class PointCloudData:
    """Configurations and their ground-truth point clouds (only completed configurations).

    Attributes
    ----------
    displacements: ``(C, m)`` float64 tendon displacements [m].
    points: ``(C, N, 3)`` float32, all clouds of a configuration concatenated (``N = S * P``).
    robot_toml: the robot description the data were generated with.
    robot_name: its name.
    limits: ``(m, 2)`` displacement limits ``[low, high]`` of the robot.
    content_hash: SHA-256 of the displacements and points (independent of HDF5 layout).
    path: the file read.
    """

    displacements: np.ndarray
    points: np.ndarray
    robot_toml: str
    robot_name: str
    limits: np.ndarray
    content_hash: str
    path: str = ""

    @property
    def n_configs(self) -> int:
        return self.displacements.shape[0]

    @property
    def n_tendons(self) -> int:
        return self.displacements.shape[1]

    @property
    def n_points(self) -> int:
        return self.points.shape[1]

    def subset(self, idx) -> PointCloudData:
        """The configurations ``idx`` (array of indices), same metadata."""
        idx = np.asarray(idx)
        return PointCloudData(
            self.displacements[idx],
            self.points[idx],
            self.robot_toml,
            self.robot_name,
            self.limits,
            self.content_hash,
            self.path,
        )


def content_hash(displacements: np.ndarray, points: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in (displacements, points):
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def angle_columns(toml_text: str) -> tuple[int, ...]:
    """Input columns that are angles: a base rotation over a full turn (column ``m``, after
    the tendons); ``()`` for other robots or a description that cannot be rebuilt."""
    import math

    from riskplan.errors import RobotDescriptionError
    from riskplan.robots import robot_from_toml

    try:
        robot = robot_from_toml(toml_text)
    except RobotDescriptionError:
        return ()
    bm = robot.base_motion
    if bm.rotation and bm.rotation_limits[1] - bm.rotation_limits[0] >= 2 * math.pi - 1e-12:
        return (robot.n_tendons,)
    return ()


def displacement_limits(toml_text: str, displacements: np.ndarray) -> np.ndarray:
    """``(m, 2)`` limits of the robot in ``toml_text``; the data range if it cannot be rebuilt."""
    from riskplan.errors import RobotDescriptionError
    from riskplan.robots import robot_from_toml

    try:
        robot = robot_from_toml(toml_text)
    except RobotDescriptionError as exc:  # a foreign or synthetic TOML: fall back to the data range
        log.warning(
            "cannot rebuild the robot from the data set's TOML (%s); using the data range as limits",
            exc,
        )
        return np.stack([displacements.min(0), displacements.max(0)], axis=1)
    # the configuration: tendon displacements, then base rotation/retraction where enabled
    lim = np.asarray(robot.configuration_limits, dtype=np.float64)
    if lim.shape != (displacements.shape[1], 2):
        raise DataFormatError(
            f"robot in the data set has {lim.shape[0]} configuration variables but displacements have {displacements.shape[1]} columns"
        )
    return lim


def read_point_clouds(path) -> PointCloudData:
    """Read a data set (:func:`riskplan.datasets.load_dataset` validates the file) for training.

    Only configurations flagged ``done`` are kept. An empty data set (no completed
    configuration) is an error: nothing can be trained or evaluated on it. Raises
    :class:`DataFormatError` naming the problem.
    """
    from riskplan.datasets import load_dataset

    ds = load_dataset(path)
    idx = np.flatnonzero(ds.done)
    if idx.size == 0 or ds.n_starts * ds.n_points == 0:
        raise DataFormatError(
            f"data set {str(path)!r} is empty: {idx.size} completed configurations of {ds.n_configs}, "
            f"{ds.n_starts}x{ds.n_points} points each"
        )
    disp = ds.displacements[idx] if idx.size < ds.n_configs else ds.displacements
    points = ds.points[idx] if idx.size < ds.n_configs else ds.points
    points = np.asarray(points, dtype=np.float32).reshape(len(idx), -1, 3)
    if not np.isfinite(disp).all():
        raise DataFormatError(f"data set {str(path)!r}: displacements contain NaN or inf")
    toml_text = str(ds.metadata["robot_toml"])
    limits = displacement_limits(toml_text, disp)
    return PointCloudData(
        disp,
        points,
        toml_text,
        str(ds.metadata["robot_name"]),
        limits,
        content_hash(disp, points),
        str(path),
    )


def check_compatible(a: PointCloudData | dict, b: PointCloudData, what: str = "data set") -> None:
    """Raise :class:`DataFormatError` if ``b`` was made with another robot than ``a``.

    ``a`` is a data set or a model's metadata dict (keys ``robot_toml``, ``n_tendons``).
    """
    toml_a = a["robot_toml"] if isinstance(a, dict) else a.robot_toml
    m_a = a["n_tendons"] if isinstance(a, dict) else a.n_tendons
    name_a = a.get("robot_name", "") if isinstance(a, dict) else a.robot_name
    if m_a != b.n_tendons:
        raise DataFormatError(
            f"{what} {b.path!r} has {b.n_tendons} tendons, the model expects {m_a}"
        )
    if _normalise_toml(toml_a) != _normalise_toml(b.robot_toml):
        raise DataFormatError(
            f"{what} {b.path!r} was made with robot {b.robot_name!r} whose description differs from the model's robot {name_a!r}"
        )


def _normalise_toml(text: str) -> str:
    return "\n".join(line.rstrip() for line in text.strip().splitlines())


def write_synthetic_dataset(
    path,
    displacements,
    points,
    *,
    robot_toml: str = "",
    robot_name: str = "synthetic",
    seed: int = 0,
) -> Path:
    """Write arrays in the data-set schema (for tests and examples without the simulator).

    ``displacements (C, m)``, ``points (C, S, P, 3)``; all configurations marked done. Uses
    the writer of :mod:`riskplan.datasets.storage`, written atomically.
    """
    import json

    from riskplan.datasets.storage import create_file, mark_complete, write_config
    from riskplan.io import atomic_path

    displacements = np.asarray(displacements, dtype=np.float64)
    points = np.asarray(points, dtype=np.float32)
    C, S, P, _ = points.shape
    m = displacements.shape[1]
    path = Path(path)
    with atomic_path(path, suffix=".h5") as tmp:
        f = create_file(
            tmp,
            displacements=displacements,
            n_starts=S,
            n_points=P,
            robot_toml=robot_toml,
            robot_name=robot_name,
            protocol_json=json.dumps({"kind": "synthetic"}),
            split="synthetic",
            seed=seed,
        )
        with f:
            for i in range(C):
                write_config(
                    f,
                    i,
                    points[i],
                    np.zeros((S, 3)),
                    np.repeat(displacements[i][None], S, 0),
                    np.zeros((S, m)),
                )
            mark_complete(f)
    return path
