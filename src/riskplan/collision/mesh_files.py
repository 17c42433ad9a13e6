"""Frames of obstacle environments: the robot base pose, and mesh files that carry their frame.

Every collision query takes robot geometry in the robot **base frame** (z along the backbone
tangent at ``s = 0``), so an environment must be in that frame too. A mesh file written by
:func:`save_environment` (``riskplan env chest``) stores its vertices in the *world* frame and a
JSON sidecar ``<mesh>.json`` beside it that names the frame and, for world-frame meshes, the
robot base pose. :func:`load_environment` reads both and returns the base-frame environment,
so the same scene gives the same answer by every path (built-in chest, file + sidecar, file +
explicit pose).

Pose convention: ``x_world = position + rotation @ x_base``; the columns of ``rotation`` are
the base x, y, z axes in the world frame. Quaternions are ``(w, x, y, z)`` (scalar first);
on the command line ``xyzw:`` marks the ROS order ``(x, y, z, w)`` (:meth:`BasePose.parse`).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from riskplan.collision.environment import Environment, check_environment
from riskplan.errors import DataFormatError, InvalidInputError

log = logging.getLogger(__name__)

SIDECAR_SUFFIX = ".json"
FRAMES = ("world", "base")
# orthonormality tolerance of a rotation read from a file or the command line
ROTATION_ATOL = 1e-6


@dataclass(frozen=True)
class BasePose:
    """Robot base pose in a world frame: ``x_world = position + rotation @ x_base``.

    ``position (3,)`` metres; ``rotation (3, 3)`` proper rotation (orthonormal, det +1).
    """

    position: np.ndarray
    rotation: np.ndarray

    def __post_init__(self):
        p = np.asarray(self.position, dtype=np.float64) if _numeric(self.position) else None
        R = np.asarray(self.rotation, dtype=np.float64) if _numeric(self.rotation) else None
        if p is None or p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InvalidInputError(
                f"base position: expected 3 finite numbers (metres), got {self.position!r}"
            )
        if R is None or R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise InvalidInputError(
                f"base rotation: expected a finite 3 x 3 matrix, got {self.rotation!r}"
            )
        if not np.allclose(R.T @ R, np.eye(3), atol=ROTATION_ATOL) or np.linalg.det(R) <= 0:
            raise InvalidInputError(
                "base rotation: expected a proper rotation matrix (orthonormal, det +1)"
            )
        p.setflags(write=False)
        R.setflags(write=False)
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "rotation", R)

    @classmethod
    def identity(cls) -> BasePose:
        return cls(np.zeros(3), np.eye(3))

    @classmethod
    def from_quaternion(cls, position, quaternion) -> BasePose:
        """From ``position (3,)`` and a quaternion ``(w, x, y, z)`` (normalised here; must be non-zero)."""
        q = np.asarray(quaternion, dtype=np.float64) if _numeric(quaternion) else None
        if q is None or q.shape != (4,) or not np.all(np.isfinite(q)):
            raise InvalidInputError(
                f"base quaternion: expected 4 finite numbers (w, x, y, z), got {quaternion!r}"
            )
        n = np.linalg.norm(q)
        if not n > 0:
            raise InvalidInputError("base quaternion: must be non-zero")
        w, x, y, z = q / n
        R = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        return cls(position, R)

    @classmethod
    def from_json(cls, path) -> BasePose:
        """From a JSON file with ``base_position`` (3,) and ``base_rotation`` (3, 3), e.g. the sidecar
        :func:`save_environment` writes."""
        meta = _read_json(Path(path))
        if "base_position" not in meta or "base_rotation" not in meta:
            raise DataFormatError(f"{path}: expected keys base_position and base_rotation")
        try:
            return cls(meta["base_position"], meta["base_rotation"])
        except InvalidInputError as exc:
            raise DataFormatError(f"{path}: {exc}") from exc

    @classmethod
    def parse(cls, text: str) -> BasePose:
        """Command-line form: ``identity`` (the mesh is already in the base frame), a JSON file
        (see :meth:`from_json`), or seven numbers (metres, quaternion; by the convention of
        :mod:`riskplan.parsing`) in one of two explicit orders:

        * ``x,y,z,qw,qx,qy,qz`` or ``wxyz:x,y,z,qw,qx,qy,qz`` -- scalar first (riskplan's order,
          also Eigen's constructor and SciPy's ``scalar_first=True``);
        * ``xyzw:x,y,z,qx,qy,qz,qw`` -- scalar last (ROS ``geometry_msgs/Quaternion``, SciPy's
          default).
        """
        if not isinstance(text, str) or not text.strip():
            raise InvalidInputError(
                f"base pose: expected 'identity', a JSON file or x,y,z,qw,qx,qy,qz, got {text!r}"
            )
        text = text.strip()
        if text.lower() == "identity":
            return cls.identity()
        order = None
        if text[:5].lower() in ("wxyz:", "xyzw:"):
            order, text = text[:4].lower(), text[5:].strip()
        p = Path(text)
        if order is None and (p.suffix.lower() == ".json" or p.is_file()):
            return cls.from_json(p)
        from riskplan.parsing import parse_numbers

        try:
            v = parse_numbers(text, "base pose", count=7)
        except InvalidInputError as exc:
            raise InvalidInputError(
                f"{exc}; expected 'identity', a JSON file, x,y,z,qw,qx,qy,qz (or wxyz:...) or "
                "xyzw:x,y,z,qx,qy,qz,qw (ROS order)"
            ) from None
        q = v[3:] if order != "xyzw" else np.r_[v[6], v[3:6]]
        return cls.from_quaternion(v[:3], q)

    def to_world(self, points_base) -> np.ndarray:
        """Base-frame points ``(..., 3)`` to world: ``p + R x``."""
        return self.position + np.asarray(points_base, dtype=np.float64) @ self.rotation.T

    def to_base(self, points_world) -> np.ndarray:
        """World points ``(..., 3)`` to the base frame: ``R^T (x - p)``."""
        return (np.asarray(points_world, dtype=np.float64) - self.position) @ self.rotation

    def to_json(self) -> dict:
        return {"base_position": self.position.tolist(), "base_rotation": self.rotation.tolist()}


def environment_in_base_frame(environment: Environment, pose: BasePose) -> Environment:
    """A world-frame 3-D environment expressed in the robot base frame of ``pose`` (a rigid motion:
    faces, obstacles and orientation are unchanged)."""
    check_environment(environment)
    if not isinstance(pose, BasePose):
        raise InvalidInputError(f"pose: expected a BasePose, got {type(pose).__name__}")
    if environment.dim != 3:
        raise InvalidInputError(
            "environment_in_base_frame: only 3-D environments have a robot base pose"
        )
    V = pose.to_base(environment.vertices)
    return Environment(
        V, environment.faces, environment.face_obstacle, environment.names, validate=False
    )


def sidecar_path(path) -> Path:
    """``chest.stl`` -> ``chest.stl.json``."""
    path = Path(path)
    return path.with_name(path.name + SIDECAR_SUFFIX)


def save_environment(
    environment: Environment,
    path,
    *,
    base_pose: BasePose | None = None,
    metadata: dict | None = None,
) -> Path:
    """Write a mesh file (world frame) and its sidecar ``<path>.json`` naming the frame, atomically.

    With ``base_pose`` the sidecar says ``"frame": "world"`` and stores the pose; without it the
    mesh is declared to be in the robot base frame (``"frame": "base"``). ``metadata`` entries
    (seed, parameters, ...) are added to the sidecar.
    """
    from riskplan.io import write_json_atomic

    check_environment(environment)
    path = Path(path)
    if path.suffix.lower() not in (".stl", ".obj", ".ply", ".off"):
        raise InvalidInputError(
            f"out: {path.name}: expected a mesh file ending in .stl, .obj, .ply or .off"
        )
    if path.is_dir():
        raise InvalidInputError(f"out: {path} is a folder; expected a mesh file name")
    meta = dict(metadata or {})
    meta["frame"] = "world" if base_pose is not None else "base"
    if base_pose is not None:
        meta.update(base_pose.to_json())
    environment.save(path)
    write_json_atomic(sidecar_path(path), meta)
    return path


def mesh_base_pose(path, base_pose: BasePose | None = None) -> BasePose:
    """The robot base pose in the frame of the mesh file ``path``.

    The frame comes from, in this order:

    1. ``base_pose`` (the mesh is in a world frame; the pose is the robot base in it). If the
       sidecar also stores a pose, the explicit one wins (logged).
    2. the sidecar ``<path>.json``: ``"frame": "base"`` (identity pose) or ``"frame": "world"``
       with ``base_position`` / ``base_rotation``. Sidecars written before the ``frame`` key
       existed but holding a base pose are world frame.

    Without either, :class:`InvalidInputError` says how to name the frame, so a world-frame mesh is
    never silently read as base frame.
    """
    path = Path(path)
    if not path.exists():
        raise InvalidInputError(f"mesh file not found: {path}")
    if path.is_dir():
        raise InvalidInputError(
            f"{path}: is a folder; expected a mesh file (.stl, .obj, .ply, .off)"
        )
    side = sidecar_path(path)
    meta = _read_json(side) if side.exists() else None
    if base_pose is not None and not isinstance(base_pose, BasePose):
        raise InvalidInputError(f"base_pose: expected a BasePose, got {type(base_pose).__name__}")
    pose = base_pose
    if pose is None and meta is not None:
        frame = meta.get("frame", "world" if "base_position" in meta else None)
        if frame not in FRAMES:
            raise DataFormatError(
                f"{side}: 'frame' must be one of {FRAMES}, got {meta.get('frame')!r}"
            )
        if frame == "world":
            # a world-frame sidecar may leave the pose open (a mesh from a segmentation volume
            # before the robot is placed): then the pose must be given
            pose = BasePose.from_json(side) if "base_pose" not in meta else None
        else:
            pose = BasePose.identity()
    elif pose is not None and meta is not None and "base_position" in meta:
        log.info("%s: using the given base pose instead of the one in %s", path, side.name)
    if pose is None:
        raise InvalidInputError(
            f"{path}: the robot base pose in the mesh's frame is unknown "
            f"({'the sidecar ' + side.name + ' names none' if meta is not None else 'no sidecar ' + side.name}); give the robot base pose in the "
            "mesh's frame (--base-pose x,y,z,qw,qx,qy,qz or a JSON file), or --base-pose identity if the mesh "
            "is already in the robot base frame"
        )
    return pose


def load_environment(
    path, *, base_pose: BasePose | None = None, split: bool = False
) -> Environment:
    """Load a mesh file as a robot-base-frame :class:`Environment`; the frame is resolved by
    :func:`mesh_base_pose` (explicit ``base_pose``, else the sidecar, else a named error)."""
    pose = mesh_base_pose(path, base_pose)
    return environment_in_base_frame(Environment.load(path, split=split), pose)


def _read_json(path: Path) -> dict:
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise InvalidInputError(f"file not found: {path}") from exc
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(f"{path}: not a readable JSON file ({exc})") from exc
    if not isinstance(meta, dict):
        raise DataFormatError(f"{path}: expected a JSON object")
    return meta


def _numeric(x) -> bool:
    try:
        return np.asarray(x).dtype.kind in "fiu"
    except Exception:  # ragged or exotic input: not numeric
        return False
