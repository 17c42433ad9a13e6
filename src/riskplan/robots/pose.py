"""The robot base pose: one class for the robot description, the collision frames and the
command line.

Convention: ``x_world = position + rotation @ x_base``; the columns of ``rotation`` are the
base x, y, z axes in the world frame. Quaternions are ``(w, x, y, z)`` (scalar first); on the
command line ``xyzw:`` marks the ROS order ``(x, y, z, w)`` (:meth:`BasePose.parse`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.io import read_json_object

__all__ = ["ROTATION_ATOL", "BasePose", "quaternion_to_matrix"]

#: orthonormality tolerance of a rotation read from a file or the command line
ROTATION_ATOL = 1e-6


def quaternion_to_matrix(q) -> np.ndarray:
    """Rotation matrix of a quaternion.

    Parameters
    ----------
    q : array_like
        ``(w, x, y, z)``, normalised here (must be non-zero).

    Returns
    -------
    numpy.ndarray
        ``(3, 3)`` proper rotation.
    """
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _numeric(x) -> bool:
    try:
        return np.asarray(x).dtype.kind in "fiu"
    except Exception:  # ragged or exotic input: not numeric
        return False


@dataclass(frozen=True, eq=False)
class BasePose:
    """Robot base pose in a world frame: ``x_world = position + rotation @ x_base``.

    Parameters
    ----------
    position : array_like
        ``(3,)`` metres (default the origin).
    rotation : array_like
        ``(3, 3)`` proper rotation, orthonormal with determinant +1 (default the identity).

    Both are stored as read-only float64 arrays; two poses are equal when their arrays are
    bit for bit (so a :class:`~riskplan.robots.RobotParams` holding one stays hashable).
    """

    position: np.ndarray = (0.0, 0.0, 0.0)
    rotation: np.ndarray = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))

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
        p, R = p.copy(), R.copy()
        p.setflags(write=False)
        R.setflags(write=False)
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "rotation", R)

    def __eq__(self, other) -> bool:
        if not isinstance(other, BasePose):
            return NotImplemented
        return (
            self.position.tobytes() == other.position.tobytes()
            and self.rotation.tobytes() == other.rotation.tobytes()
        )

    def __hash__(self) -> int:
        return hash((self.position.tobytes(), self.rotation.tobytes()))

    @property
    def matrix(self) -> np.ndarray:
        """``(3, 3)`` the rotation (the same array as :attr:`rotation`)."""
        return self.rotation

    @property
    def is_identity(self) -> bool:
        """Whether the pose is exactly the identity (zero position, identity rotation)."""
        return bool(np.all(self.position == 0.0) and np.all(self.rotation == np.eye(3)))

    @classmethod
    def identity(cls) -> BasePose:
        """The identity pose (the mesh is already in the base frame).

        Returns
        -------
        BasePose
        """
        return cls()

    @classmethod
    def from_quaternion(cls, position, quaternion) -> BasePose:
        """From a position and a quaternion.

        Parameters
        ----------
        position : array_like
            ``(3,)`` metres.
        quaternion : array_like
            ``(w, x, y, z)``, normalised here; must be non-zero.

        Returns
        -------
        BasePose
        """
        q = np.asarray(quaternion, dtype=np.float64) if _numeric(quaternion) else None
        if q is None or q.shape != (4,) or not np.all(np.isfinite(q)):
            raise InvalidInputError(
                f"base quaternion: expected 4 finite numbers (w, x, y, z), got {quaternion!r}"
            )
        if not np.linalg.norm(q) > 0:
            raise InvalidInputError("base quaternion: must be non-zero")
        return cls(position, quaternion_to_matrix(q))

    @classmethod
    def from_json(cls, path) -> BasePose:
        """From a JSON file with ``base_position`` (3,) and ``base_rotation`` (3, 3), e.g. the
        sidecar :func:`riskplan.collision.mesh_files.save_environment` writes.

        Parameters
        ----------
        path : str or os.PathLike
            The JSON file.

        Returns
        -------
        BasePose
        """
        meta = read_json_object(path)
        if "base_position" not in meta or "base_rotation" not in meta:
            raise DataFormatError(f"{path}: expected keys base_position and base_rotation")
        try:
            return cls(meta["base_position"], meta["base_rotation"])
        except InvalidInputError as exc:
            raise DataFormatError(f"{path}: {exc}") from exc

    @classmethod
    def parse(cls, text: str) -> BasePose:
        """The command-line form of a pose.

        ``identity`` (the mesh is already in the base frame), a JSON file (see
        :meth:`from_json`), or seven numbers (metres, quaternion; by the convention of
        :mod:`riskplan.parsing`) in one of two explicit orders:

        * ``x,y,z,qw,qx,qy,qz`` or ``wxyz:x,y,z,qw,qx,qy,qz`` -- scalar first (riskplan's order,
          also Eigen's constructor and SciPy's ``scalar_first=True``);
        * ``xyzw:x,y,z,qx,qy,qz,qw`` -- scalar last (ROS ``geometry_msgs/Quaternion``, SciPy's
          default).

        Parameters
        ----------
        text : str
            The option's value.

        Returns
        -------
        BasePose
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
        """Base-frame points to the world frame, ``p + R x``.

        Parameters
        ----------
        points_base : array_like
            ``(..., 3)`` points in the base frame.

        Returns
        -------
        numpy.ndarray
            ``(..., 3)`` world points.
        """
        return self.position + np.asarray(points_base, dtype=np.float64) @ self.rotation.T

    def to_base(self, points_world) -> np.ndarray:
        """World points to the base frame, ``Rᵀ (x − p)``.

        Parameters
        ----------
        points_world : array_like
            ``(..., 3)`` world points.

        Returns
        -------
        numpy.ndarray
            ``(..., 3)`` points in the base frame.
        """
        return (np.asarray(points_world, dtype=np.float64) - self.position) @ self.rotation

    def to_json(self) -> dict:
        """The pose as the sidecar's keys.

        Returns
        -------
        dict
            ``base_position`` (3 floats) and ``base_rotation`` (3 lists of 3).
        """
        return {"base_position": self.position.tolist(), "base_rotation": self.rotation.tolist()}
