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

FORMAT = "riskplan-dataset"
SUPPORTED_VERSIONS = (1,)


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
            self.displacements[idx], self.points[idx], self.robot_toml, self.robot_name, self.limits,
            self.content_hash, self.path,
        )


def content_hash(displacements: np.ndarray, points: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in (displacements, points):
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def robot_from_toml(toml_text: str):
    """Rebuild the robot from its TOML text, or ``None`` if the robot module cannot."""
    try:
        from riskplan import robots
    except ImportError:  # robot area not installed
        return None
    for fn_name in ("robot_from_toml", "from_toml", "loads"):
        fn = getattr(robots, fn_name, None)
        if fn is not None:
            return fn(toml_text)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "robot.toml"
        p.write_text(toml_text)
        return robots.load_robot(p)


def displacement_limits(toml_text: str, displacements: np.ndarray) -> np.ndarray:
    """``(m, 2)`` limits of the robot in ``toml_text``; the data range if it cannot be rebuilt."""
    robot = None
    try:
        robot = robot_from_toml(toml_text)
    except Exception as exc:  # a foreign or synthetic TOML: fall back to the data range
        log.warning("cannot rebuild the robot from the data set's TOML (%s); using the data range as limits", exc)
    if robot is not None:
        lim = np.asarray(robot.displacement_limits, dtype=np.float64)
        if lim.shape == (displacements.shape[1], 2):
            return lim
        raise DataFormatError(
            f"robot in the data set has {lim.shape[0]} tendons but displacements have {displacements.shape[1]} columns"
        )
    return np.stack([displacements.min(0), displacements.max(0)], axis=1)


def read_point_clouds(path) -> PointCloudData:
    """Read and validate a data set file; raises :class:`DataFormatError` naming the problem.

    Only configurations flagged ``done`` are kept. An empty data set (no completed
    configuration) is an error: nothing can be trained or evaluated on it.
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"data set {str(path)!r}: no such file")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise DataFormatError(f"data set {str(path)!r}: not a readable HDF5 file ({exc})") from exc
    with f:
        fmt = f.attrs.get("format")
        if isinstance(fmt, bytes):
            fmt = fmt.decode()
        if fmt != FORMAT:
            raise DataFormatError(f"data set {str(path)!r}: attribute format={fmt!r}, expected {FORMAT!r}")
        ver = int(f.attrs.get("format_version", -1))
        if ver not in SUPPORTED_VERSIONS:
            raise DataFormatError(f"data set {str(path)!r}: format_version={ver} is not supported (expected one of {SUPPORTED_VERSIONS})")
        for key in ("displacements", "points"):
            if key not in f:
                raise DataFormatError(f"data set {str(path)!r}: missing data set {key!r}")
        disp = np.asarray(f["displacements"][...], dtype=np.float64)
        if disp.ndim != 2:
            raise DataFormatError(f"data set {str(path)!r}: displacements has shape {disp.shape}, expected (C, m)")
        C, m = disp.shape
        pshape = f["points"].shape
        if len(pshape) != 4 or pshape[0] != C or pshape[3] != 3:
            raise DataFormatError(
                f"data set {str(path)!r}: points has shape {pshape}, expected (C={C}, S, P, 3) matching displacements {disp.shape}"
            )
        done = np.asarray(f["done"][...], dtype=bool) if "done" in f else np.ones(C, dtype=bool)
        if done.shape != (C,):
            raise DataFormatError(f"data set {str(path)!r}: done has shape {done.shape}, expected ({C},)")
        idx = np.flatnonzero(done)
        if idx.size == 0 or pshape[1] * pshape[2] == 0:
            raise DataFormatError(f"data set {str(path)!r} is empty: {idx.size} completed configurations of {C}, {pshape[1]}x{pshape[2]} points each")
        points = np.asarray(f["points"][...] if idx.size == C else f["points"][idx], dtype=np.float32)
        disp = disp[idx]
        robot_toml = f.attrs.get("robot_toml", "")
        robot_name = f.attrs.get("robot_name", "")
    robot_toml = robot_toml.decode() if isinstance(robot_toml, bytes) else str(robot_toml)
    robot_name = robot_name.decode() if isinstance(robot_name, bytes) else str(robot_name)
    points = points.reshape(points.shape[0], -1, 3)
    if not np.isfinite(disp).all():
        raise DataFormatError(f"data set {str(path)!r}: displacements contain NaN or inf")
    if not np.isfinite(points).all():
        bad = int((~np.isfinite(points).all(axis=(1, 2))).sum())
        raise DataFormatError(f"data set {str(path)!r}: points contain NaN or inf in {bad} configurations")
    limits = displacement_limits(robot_toml, disp)
    return PointCloudData(disp, points, robot_toml, robot_name, limits, content_hash(disp, points), str(path))


def check_compatible(a: PointCloudData | dict, b: PointCloudData, what: str = "data set") -> None:
    """Raise :class:`DataFormatError` if ``b`` was made with another robot than ``a``.

    ``a`` is a data set or a model's metadata dict (keys ``robot_toml``, ``n_tendons``).
    """
    toml_a = a["robot_toml"] if isinstance(a, dict) else a.robot_toml
    m_a = a["n_tendons"] if isinstance(a, dict) else a.n_tendons
    name_a = a.get("robot_name", "") if isinstance(a, dict) else a.robot_name
    if m_a != b.n_tendons:
        raise DataFormatError(f"{what} {b.path!r} has {b.n_tendons} tendons, the model expects {m_a}")
    if _normalise_toml(toml_a) != _normalise_toml(b.robot_toml):
        raise DataFormatError(
            f"{what} {b.path!r} was made with robot {b.robot_name!r} whose description differs from the model's robot {name_a!r}"
        )


def _normalise_toml(text: str) -> str:
    return "\n".join(line.rstrip() for line in text.strip().splitlines())


def write_synthetic_dataset(path, displacements, points, *, robot_toml: str = "", robot_name: str = "synthetic", seed: int = 0) -> Path:
    """Write arrays in the data-set schema (for tests and examples without the simulator).

    ``displacements (C, m)``, ``points (C, S, P, 3)``; all configurations marked done.
    """
    import json

    import h5py

    from riskplan.io import atomic_path

    displacements = np.asarray(displacements, dtype=np.float64)
    points = np.asarray(points, dtype=np.float32)
    path = Path(path)
    with atomic_path(path, suffix=".h5") as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = FORMAT
            f.attrs["format_version"] = 1
            f.attrs["riskplan_version"] = _version()
            f.attrs["robot_toml"] = robot_toml
            f.attrs["robot_name"] = robot_name
            f.attrs["protocol"] = json.dumps({"kind": "synthetic"})
            f.attrs["seed"] = seed
            f.attrs["created"] = "synthetic"
            f["displacements"] = displacements
            f["points"] = points
            f["tips"] = np.zeros(points.shape[:2] + (3,))
            f["starts"] = np.repeat(displacements[:, None, :], points.shape[1], axis=1)
            f["done"] = np.ones(displacements.shape[0], dtype=bool)
    return path


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("riskplan")
    except PackageNotFoundError:  # pragma: no cover
        return "0+unknown"
