"""Base pose, gravity switch, base rotation and retraction of a :class:`~riskplan.robots.TendonRobot`.

The bodies of the robot facade's methods that derive a robot (another base pose, gravity on
or off, the exposed part of a retracted robot) or solve a robot whose base turns about its
axis and/or retracts (the lab's configuration ``(tendons, rotation, retraction)``). Each
takes the robot first; the methods of ``TendonRobot`` (documented there) call them.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from riskplan._validation import as_array, check_range
from riskplan.errors import InvalidInputError
from riskplan.robots.params import BaseMotion, Disks, Gravity, rpy_to_matrix
from riskplan.robots.pose import BasePose, quaternion_to_matrix
from riskplan.robots.shape import RodShape, rotation_z, shift_polynomial

__all__ = [
    "check_base_motion",
    "configuration_limits",
    "configuration_to_displacements",
    "configuration_to_tensions",
    "interpolate_configurations",
    "retracted",
    "solve_moved",
    "split_configuration",
    "with_base_pose",
    "with_gravity",
]


def configuration_limits(robot) -> np.ndarray:
    """``(n_config, 2)`` ``[low, high]``: tendon displacements [m], then rotation [rad] and
    retraction [m] where enabled (the lab's configuration order).

    Parameters
    ----------
    robot : TendonRobot
        The robot.

    Returns
    -------
    numpy.ndarray
        ``(n_config, 2)`` limits ``[low, high]``.
    """
    rows = [robot.displacement_limits]
    bm = robot.base_motion
    if bm.rotation:
        rows.append(np.array([bm.rotation_limits]))
    if bm.retraction:
        rows.append(np.array([bm.retraction_limits]))
    return np.concatenate(rows, axis=0)


def split_configuration(robot, q, validate: bool = True):
    """``(tendon part (..., m), rotation (...) or None, retraction (...) or None)`` of
    configurations ``q (..., n_config)`` in the lab's order (tendons, rotation, retraction).

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    q : array_like, shape (..., n_config)
        Configurations.
    validate : bool
        Check ``q`` (finite numbers, its last dimension).

    Returns
    -------
    tuple
        Tendon displacements ``(..., m)`` [m], rotation ``(...)`` [rad] or None, retraction
        ``(...)`` [m] or None.
    """
    q = as_array(q, "configuration", min_ndim=1) if validate else np.asarray(q, dtype=float)
    if q.shape[-1] != robot.n_config:
        raise InvalidInputError(
            f"configuration: expected last dimension {robot.n_config} ({robot.n_tendons} tendons"
            f"{' + rotation' if robot.base_motion.rotation else ''}"
            f"{' + retraction' if robot.base_motion.retraction else ''}), got shape {q.shape}"
        )
    m = robot.n_tendons
    rot = q[..., m] if robot.base_motion.rotation else None
    ret = q[..., -1] if robot.base_motion.retraction else None
    return q[..., :m], rot, ret


def with_base_pose(robot, position=(0.0, 0.0, 0.0), *, rotation=None, rpy=None, quaternion=None):
    """:meth:`TendonRobot.with_base_pose` of ``robot``.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    position : array_like, shape (3,)
        Base position [m] in the world frame.
    rotation, rpy, quaternion : array_like, optional
        One orientation: a rotation matrix ``(3, 3)``, roll-pitch-yaw ``(3,)`` [rad]
        (:func:`~riskplan.robots.params.rpy_to_matrix`) or a quaternion ``(4,)``; default
        the identity.

    Returns
    -------
    TendonRobot
        A robot of the same type with that base pose.
    """
    given = [
        k
        for k, v in (("rotation", rotation), ("rpy", rpy), ("quaternion", quaternion))
        if v is not None
    ]
    if len(given) > 1:
        raise InvalidInputError(f"with_base_pose: give one orientation, got {given}")
    pos = as_array(position, "position", shape=(3,))
    if rotation is not None:
        Rm = as_array(rotation, "rotation", shape=(3, 3))
        if not np.allclose(Rm.T @ Rm, np.eye(3), atol=1e-8) or np.linalg.det(Rm) <= 0:
            raise InvalidInputError(
                "rotation: expected a proper rotation matrix (R^T R = I, det R = 1)"
            )
    elif quaternion is not None:
        q = as_array(quaternion, "quaternion", shape=(4,))
        if np.linalg.norm(q) < 1e-12:
            raise InvalidInputError("quaternion: must be non-zero")
        Rm = quaternion_to_matrix(q)
    else:
        Rm = rpy_to_matrix(as_array(rpy if rpy is not None else (0, 0, 0), "rpy", shape=(3,)))
    base = BasePose(tuple(float(v) for v in pos), tuple(tuple(float(v) for v in r) for r in Rm))
    return type(robot)(replace(robot.params, base=base))


def with_gravity(robot, enabled: bool = True, vector=None):
    """:meth:`TendonRobot.with_gravity` of ``robot``.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    enabled : bool
        Gravity on or off.
    vector : array_like, shape (3,), optional
        Gravitational acceleration [m/s²] in the world frame (default the robot's).

    Returns
    -------
    TendonRobot
        A robot of the same type with that gravity.
    """
    if not isinstance(enabled, (bool, np.bool_)):
        raise InvalidInputError(
            f"enabled: expected True or False, got {enabled!r} ({type(enabled).__name__})"
        )
    vec = (
        robot.params.gravity.vector
        if vector is None
        else tuple(as_array(vector, "vector", shape=(3,)).tolist())
    )
    return type(robot)(replace(robot.params, gravity=Gravity(bool(enabled), vec)))


def interpolate_configurations(robot, a, b, t) -> np.ndarray:
    """:meth:`TendonRobot.interpolate_configurations` of ``robot``.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    a, b : array_like, shape (..., n_config)
        End configurations.
    t : array_like
        Fractions, broadcast against the batch shape.

    Returns
    -------
    numpy.ndarray
        ``a + t (b − a)``; a full-turn rotation interpolates along the shorter arc, wrapped to
        ``[−π, π)``.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    out = a + t * (b - a)
    bm = robot.base_motion
    if bm.rotation and bm.rotation_limits[1] - bm.rotation_limits[0] >= 2 * math.pi - 1e-12:
        j = robot.n_tendons
        diff = np.mod(b[..., j] - a[..., j] + math.pi, 2 * math.pi) - math.pi
        out[..., j] = np.mod(a[..., j] + t[..., 0] * diff + math.pi, 2 * math.pi) - math.pi
    return out


def configuration_to_displacements(robot, q, *, validate: bool = True) -> np.ndarray:
    """:meth:`TendonRobot.configuration_to_displacements` of ``robot``.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    q : array_like, shape (..., n_config)
        Configurations whose tendon part is tensions [N].
    validate : bool
        Check ``q``.

    Returns
    -------
    numpy.ndarray
        ``q`` with the tendon part as displacements [m] at each configuration's retraction.
    """
    return _convert_tendon_part(robot, q, robot.displacements_for_tensions, validate)


def configuration_to_tensions(robot, q, *, validate: bool = True) -> np.ndarray:
    """:meth:`TendonRobot.configuration_to_tensions` of ``robot``.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    q : array_like, shape (..., n_config)
        Configurations whose tendon part is displacements [m].
    validate : bool
        Check ``q``.

    Returns
    -------
    numpy.ndarray
        ``q`` with the tendon part as tensions [N] at each configuration's retraction.
    """
    return _convert_tendon_part(robot, q, robot.tensions_for_displacements, validate)


def _convert_tendon_part(robot, q, convert, validate: bool) -> np.ndarray:
    """``q`` with its tendon part replaced by ``convert(part, retraction=..., validate=...)``
    at each configuration's own retraction; rotation and retraction unchanged."""
    q = np.array(q, dtype=np.float64)
    part, _, ret = robot.split_configuration(q, validate=validate)
    out = q.copy()
    out[..., : robot.n_tendons] = convert(part, retraction=ret, validate=validate)
    return out


def check_base_motion(robot, rotation, retraction, batch_shape) -> tuple:
    """:meth:`TendonRobot.check_base_motion` of ``robot``.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    rotation : array_like or None
        Base rotation [rad], scalar or of ``batch_shape``.
    retraction : array_like or None
        Retraction [m], scalar or of ``batch_shape``.
    batch_shape : tuple of int
        The batch shape to broadcast to.

    Returns
    -------
    tuple
        ``(rotation, retraction)``, each a float64 array of ``batch_shape`` within its limits,
        or None where not given.
    """
    bm = robot.base_motion
    out = []
    for name, value, enabled, lim, unit in (
        ("rotation", rotation, bm.rotation, bm.rotation_limits, "rad"),
        ("retraction", retraction, bm.retraction, bm.retraction_limits, "m"),
    ):
        if value is None:
            out.append(None)
            continue
        if not enabled:
            raise InvalidInputError(
                f"{name}: robot {robot.name!r} has no base {name} (its file does not enable it)"
            )
        arr = as_array(value, name)
        try:
            arr = np.broadcast_to(arr, batch_shape)
        except ValueError:
            raise InvalidInputError(
                f"{name}: expected a scalar or shape {batch_shape}, got {arr.shape}"
            ) from None
        check_range(arr, f"{name} [{unit}]", low=lim[0], high=lim[1])
        out.append(np.ascontiguousarray(arr, dtype=np.float64))
    return tuple(out)


def retracted(robot, retraction: float):
    """:meth:`TendonRobot.retracted` of ``robot``.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    retraction : float
        Retracted length [m].

    Returns
    -------
    TendonRobot
        The exposed part (cached per value, at most 256).
    """
    rho = float(retraction)
    cache = robot.__dict__.setdefault("_retracted", {})
    if rho in cache:
        return cache[rho]
    p = robot.params
    bb = p.backbone
    L = bb.length - rho
    if rho == 0.0:
        sub_bb = bb
    else:
        sub_bb = replace(bb, length=L, step=L / bb.n_steps)
    tendons = tuple(
        replace(t, theta=shift_polynomial(t.theta, rho), radius=shift_polynomial(t.radius, rho))
        for t in p.tendons
    )
    kept = tuple(x - rho for x in p.disks.positions if x > rho)
    disks = Disks(len(kept), p.disks.radius, p.disks.thickness, p.disks.density, kept)
    sub = type(robot)(
        replace(
            p,
            backbone=sub_bb,
            disks=disks,
            tendons=tendons,
            base=BasePose(),
            base_motion=BaseMotion(),
        )
    )
    if len(cache) >= 256:  # bounded: data sets draw many retractions
        cache.pop(next(iter(cache)))
    cache[rho] = sub
    return sub


def per_retraction(robot, method: str, values, retraction, validate: bool) -> np.ndarray:
    """``method`` of :meth:`retracted` robots, grouped by retraction value."""
    by_disp = method == "tensions_for_displacements"
    check = robot.check_displacements if by_disp else robot.check_tensions
    arr = check(values) if validate else np.asarray(values, dtype=float)
    _, ret = robot.check_base_motion(None, retraction, arr.shape[:-1])
    flat = arr.reshape(-1, robot.n_tendons)
    rflat = ret.reshape(-1)
    out = np.empty_like(flat)
    for rho in np.unique(rflat):
        idx = np.flatnonzero(rflat == rho)
        out[idx] = getattr(robot.retracted(rho), method)(flat[idx], validate=False)
    return out.reshape(arr.shape)


def solve_moved(robot, by_tension: bool, values, rotation, retraction, validate) -> RodShape:
    """Shapes with base rotation and/or retraction (see :meth:`solve_tensions`).

    Parameters
    ----------
    robot : TendonRobot
        The robot (gravity off).
    by_tension : bool
        ``values`` are tensions [N] (else displacements [m]).
    values : array_like, shape (..., m)
        Tendon tensions or displacements.
    rotation, retraction : array_like or None
        Base rotation [rad] and retraction [m] per configuration.
    validate : bool
        Check the inputs.

    Returns
    -------
    RodShape
        The shapes in the world frame.
    """
    if robot.loaded:
        raise InvalidInputError(
            "base rotation/retraction with gravity is not modelled (the exposed part's "
            "load would depend on the retracted part); switch gravity off"
        )
    check = robot.check_tensions if by_tension else robot.check_displacements
    arr = check(values) if validate else np.asarray(values, dtype=float)
    batch = arr.shape[:-1]
    rot, ret = robot.check_base_motion(rotation, retraction, batch)
    flat = np.ascontiguousarray(arr.reshape(-1, robot.n_tendons))
    B, n, m = flat.shape[0], robot._n + 1, robot.n_tendons
    rflat = np.zeros(B) if ret is None else ret.reshape(-1)
    P = np.empty((B, n, 3))
    Rs = np.empty((B, n, 3, 3))
    tau = np.empty((B, m))
    S = np.empty((B, n))
    for rho in np.unique(rflat):
        idx = np.flatnonzero(rflat == rho)
        sub = robot.retracted(rho)
        solve = sub.solve_tensions if by_tension else sub.solve_displacements
        shape = solve(flat[idx], validate=False)
        P[idx], Rs[idx], tau[idx] = shape.positions, shape.rotations, shape.tensions
        S[idx] = shape.s
    if rot is not None:
        Rz = rotation_z(rot.reshape(-1))
        P = np.einsum("bij,bnj->bni", Rz, P)
        Rs = np.einsum("bij,bnjk->bnik", Rz, Rs)
    shape = robot._to_world(P, Rs, tau, batch)
    # without retraction every row holds the whole robot's stations
    s = S.reshape(batch + (n,)) if (ret is not None and batch) else S[0].copy()
    s.flags.writeable = False
    return RodShape(s, shape.positions, shape.rotations, shape.tensions)
