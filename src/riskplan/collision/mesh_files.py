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
The pose is :class:`riskplan.robots.pose.BasePose`, the same class a robot file's ``[base]``
table gives (re-exported here).
"""

from __future__ import annotations

import logging
from pathlib import Path

from riskplan.collision.environment import Environment, check_environment
from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.io import read_json_object
from riskplan.robots.pose import ROTATION_ATOL, BasePose  # noqa: F401 - the one BasePose

log = logging.getLogger(__name__)

SIDECAR_SUFFIX = ".json"
FRAMES = ("world", "base")


def environment_in_base_frame(environment: Environment, pose: BasePose) -> Environment:
    """A world-frame 3-D environment expressed in the robot base frame of ``pose``.

    A rigid motion ``x_base = R^T (x_world - p)``: faces, obstacles and orientation are unchanged.

    Parameters
    ----------
    environment : Environment
        3-D obstacles in the world frame (m).
    pose : BasePose
        The robot base in the world frame (position ``p``, rotation ``R``).

    Returns
    -------
    Environment
        The same obstacles in the base frame.
    """
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
    """Write a mesh file and its sidecar ``<path>.json`` naming the frame, atomically.

    Parameters
    ----------
    environment : Environment
        3-D obstacles (m).
    path : str or path
        The mesh file; the format follows the suffix.
    base_pose : BasePose, optional
        With it the sidecar says ``"frame": "world"`` and stores the pose; without it the mesh
        is declared to be in the robot base frame (``"frame": "base"``).
    metadata : dict, optional
        Entries (seed, parameters, ...) added to the sidecar.

    Returns
    -------
    pathlib.Path
        ``path``.
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

    Parameters
    ----------
    path : str or path
        The mesh file (its sidecar is ``<path>.json``).
    base_pose : BasePose, optional
        An explicit pose.

    Returns
    -------
    BasePose
        The robot base in the mesh's frame (identity for a base-frame mesh).
    """
    path = Path(path)
    if not path.exists():
        raise InvalidInputError(f"mesh file not found: {path}")
    if path.is_dir():
        raise InvalidInputError(
            f"{path}: is a folder; expected a mesh file (.stl, .obj, .ply, .off)"
        )
    side = sidecar_path(path)
    meta = read_json_object(side) if side.exists() else None
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
    path,
    *,
    base_pose: BasePose | None = None,
    split: bool = False,
    robot_length: float | None = None,
    source: str | None = None,
) -> Environment:
    """Load a mesh file as a robot-base-frame :class:`Environment`.

    The frame is resolved by :func:`mesh_base_pose` (explicit ``base_pose``, else the sidecar,
    else a named error).

    Parameters
    ----------
    path : str or path
        Mesh file (STL/OBJ/PLY/OFF), in metres.
    base_pose : BasePose, optional
        The robot base in the mesh's (world) frame; wins over a pose in the sidecar.
    split : bool
        One obstacle per connected component (:meth:`Environment.load`).
    robot_length : float, optional
        The robot's length (m): the mesh's extent is first judged against it by
        :func:`~riskplan.collision.geometry.check_metre_scale`, and a mesh more than
        ``MILLIMETRE_FACTOR`` robot lengths across is refused as millimetres.
    source : str, optional
        The option or field named in that error (default: the path).

    Returns
    -------
    Environment
        The obstacles in the robot base frame.
    """
    env = Environment.load(path, split=split)
    if robot_length is not None:
        from riskplan.collision.geometry import check_metre_scale

        check_metre_scale(env.vertices, robot_length, source=source or str(path))
    pose = mesh_base_pose(path, base_pose)
    return environment_in_base_frame(env, pose)
