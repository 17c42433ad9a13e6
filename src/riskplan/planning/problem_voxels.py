"""The lab's voxel obstacles of a problem file (``[voxel_environment]``, read by
:func:`riskplan.planning.load_problem`): the ``VoxelOctree`` file format and the frames that
place it relative to the robot."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from riskplan.errors import InvalidInputError


@dataclass(frozen=True, eq=False)
class VoxelGrid:
    """Occupied cells of the lab's ``VoxelOctree`` (a regular grid stored in 4×4×4 blocks).

    Attributes
    ----------
    limits: ``(3, 2)`` lower and upper corner of the grid per axis (m, voxel frame).
    dimension: cells per axis ``N``.
    occupied: ``(K, 3)`` integer indices ``(ix, iy, iz)`` of the occupied cells.
    """

    limits: np.ndarray
    dimension: int
    occupied: np.ndarray

    @property
    def spacing(self) -> np.ndarray:
        """``(3,)`` cell size (m)."""
        return (self.limits[:, 1] - self.limits[:, 0]) / self.dimension

    def centers(self) -> np.ndarray:
        """``(K, 3)`` centres of the occupied cells, voxel frame (m)."""
        return self.limits[:, 0] + (self.occupied + 0.5) * self.spacing


def read_voxel_octree(path) -> VoxelGrid:
    """Read the lab's ``VoxelOctree`` file (``.msgpack`` or ``.json``; ``.toml`` is not read).

    Format (``collision::VoxelOctree::to_toml`` and its msgpack/JSON twins): ``{"VoxelOctree":
    {"dimension": N, "xlimits": [lo, hi], "ylimits", "zlimits", "data": [[bx, by, bz, bits],
    ...]}}``; block ``(bx, by, bz)`` covers cells ``4 b + (0..3)`` and cell ``(x, y, z)`` of a
    block is occupied when bit ``16 x + 4 y + z`` of ``bits`` is set (``VoxelOctree::bitmask``).
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise InvalidInputError(f"voxel file {str(p)!r}: cannot read ({exc})") from exc
    if p.suffix == ".msgpack":
        try:
            import msgpack
        except ImportError as exc:  # pragma: no cover - an optional extra
            raise InvalidInputError(
                f"voxel file {str(p)!r}: reading .msgpack needs the 'msgpack' package "
                "(pip install 'riskplan[mesh]'), or give the .json form"
            ) from exc
        try:
            doc = msgpack.unpackb(raw, strict_map_key=False)
        except Exception as exc:
            raise InvalidInputError(f"voxel file {str(p)!r}: not valid msgpack ({exc})") from exc
    elif p.suffix == ".json":
        import json

        try:
            doc = json.loads(raw)
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InvalidInputError(f"voxel file {str(p)!r}: not valid JSON ({exc})") from exc
    else:
        raise InvalidInputError(
            f"voxel file {str(p)!r}: expected .msgpack or .json, got {p.suffix!r}"
        )
    try:
        t = doc["VoxelOctree"]
        N = int(t["dimension"])
        limits = np.array([t["xlimits"], t["ylimits"], t["zlimits"]], dtype=np.float64)
        data = np.array(t["data"], dtype=object).reshape(-1, 4)
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInputError(f"voxel file {str(p)!r}: not a VoxelOctree ({exc})") from exc
    if N <= 0 or N % 4 or limits.shape != (3, 2) or np.any(limits[:, 1] <= limits[:, 0]):
        raise InvalidInputError(f"voxel file {str(p)!r}: bad dimension {N} or limits")
    blocks = data[:, :3].astype(np.int64)
    bits = np.array([int(b) for b in data[:, 3]], dtype=np.uint64)
    k = np.arange(64, dtype=np.uint64)
    on = ((bits[:, None] >> k[None, :]) & np.uint64(1)).astype(bool)  # (B, 64)
    b_idx, bit = np.nonzero(on)
    local = np.stack([bit // 16, (bit // 4) % 4, bit % 4], axis=-1)
    occupied = 4 * blocks[b_idx] + local
    if occupied.size and (occupied.min() < 0 or occupied.max() >= N):
        raise InvalidInputError(f"voxel file {str(p)!r}: blocks outside the {N}^3 grid")
    return VoxelGrid(limits, N, occupied)


@dataclass(frozen=True, eq=False)
class VoxelEnvironment:
    """The lab's ``[voxel_environment]``: a voxel obstacle file and its frames.

    Conventions, established from the lab's code (``motion_planning::VoxelEnvironment`` in
    Kuntz-Lab/interactive-rate-tendons) and checked on its data (tests/planning/test_problem.py):

    * ``rotation_quat`` is **scalar first** ``(w, x, y, z)`` (``Eigen::Quaterniond(w, x, y, z)``);
      its matrix ``R`` takes robot-frame points into the voxel frame, ``x_voxel = R x_robot``
      (``rotate_point``), so ``x_robot = Rᵀ x_voxel``.
    * ``scaling`` and ``translation`` take the segmentation image's physical frame (mm) to the
      voxel frame (m): ``x_voxel = scaling (x_image + translation)``
      (``translate_and_scale_image``). The voxel file itself is already in the voxel frame.
    """

    filename: Path | None
    scaling: float = 1.0
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    interior_filename: Path | None = None

    @property
    def rotation(self) -> np.ndarray:
        """``(3, 3)`` ``R`` with ``x_voxel = R x_robot``."""
        from riskplan.robots.pose import quaternion_to_matrix

        return quaternion_to_matrix(self.rotation_quat)

    def image_to_voxel(self, points) -> np.ndarray:
        """``(..., 3)`` segmentation-image points (its physical units) to the voxel frame (m)."""
        return self.scaling * (np.asarray(points, dtype=np.float64) + np.asarray(self.translation))

    def voxel_to_robot(self, points) -> np.ndarray:
        """``(..., 3)`` voxel-frame points to the robot (base) frame: ``Rᵀ x``."""
        return np.asarray(points, dtype=np.float64) @ self.rotation

    def robot_to_voxel(self, points) -> np.ndarray:
        """``(..., 3)`` robot-frame points to the voxel frame: ``R x``."""
        return np.asarray(points, dtype=np.float64) @ self.rotation.T

    def load(self) -> VoxelGrid:
        """The voxel file's occupied cells (:func:`read_voxel_octree`)."""
        if self.filename is None:
            raise InvalidInputError("voxel_environment: no filename")
        return read_voxel_octree(self.filename)

    def obstacle_centers(self) -> np.ndarray:
        """``(K, 3)`` centres of the occupied cells in the robot frame (m)."""
        return self.voxel_to_robot(self.load().centers())
