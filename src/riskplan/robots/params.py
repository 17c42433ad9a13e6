"""Robot descriptions: frozen dataclasses and the TOML format (docs/robots.md lists every key).

A robot file describes the backbone (a Cosserat rod), the separator disks, any number of
tendons with polynomial routing ``theta(s)``, ``r(s)`` (Rucker & Webster 2011, Sec. II), the
tendon stiffness used for displacement input, limits, gravity, the base pose, and the
hysteresis (path-dependence) parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from riskplan.errors import RobotDescriptionError
from riskplan.robots.pose import BasePose, quaternion_to_matrix
from riskplan.robots.toml_fields import (
    check_unknown_keys,
    field_integer,
    field_number,
    field_table,
    field_vector,
    suggest_key,
)

__all__ = [
    "Backbone",
    "BaseMotion",
    "Disks",
    "Gravity",
    "HysteresisParams",
    "RobotParams",
    "Tendon",
    "rpy_to_matrix",
    "suggest_key",
]


@dataclass(frozen=True)
class Backbone:
    """Elastic backbone rod (SI units). ``shear_modulus = E / (2 (1 + nu))`` unless given."""

    length: float
    outer_radius: float
    inner_radius: float
    youngs_modulus: float
    shear_modulus: float
    density: float
    step: float

    @property
    def area(self) -> float:
        return math.pi * (self.outer_radius**2 - self.inner_radius**2)

    @property
    def second_moment(self) -> float:
        """Area moment ``I = pi (ro^4 - ri^4) / 4``; polar moment ``J = 2 I``."""
        return math.pi * (self.outer_radius**4 - self.inner_radius**4) / 4.0

    @property
    def kse(self) -> np.ndarray:
        """Diagonal of ``K_se = diag(G A, G A, E A)`` (shear, shear, extension)."""
        A = self.area
        return np.array([self.shear_modulus * A, self.shear_modulus * A, self.youngs_modulus * A])

    @property
    def kbt(self) -> np.ndarray:
        """Diagonal of ``K_bt = diag(E I, E I, G J)`` (bending, bending, torsion)."""
        I = self.second_moment
        return np.array(
            [self.youngs_modulus * I, self.youngs_modulus * I, self.shear_modulus * 2 * I]
        )

    @property
    def n_steps(self) -> int:
        """Number of integration steps: ``ceil(length / step)`` (the step is shortened to fit)."""
        return max(1, math.ceil(self.length / self.step - 1e-9))


@dataclass(frozen=True)
class Disks:
    """Separator disks (geometry for sensing; mass smeared along the backbone under gravity)."""

    count: int
    radius: float
    thickness: float
    density: float
    positions: tuple[float, ...]

    @property
    def mass(self) -> float:
        return self.density * math.pi * self.radius**2 * self.thickness


@dataclass(frozen=True)
class Tendon:
    """One tendon: routing ``theta(s) = sum_k theta[k] s^k`` (rad), ``r(s) = sum_k radius[k] s^k`` (m).

    ``stiffness`` (N/m) is the series stiffness of the tendon between actuator and tip (inf:
    inextensible). ``displacement_limits = (low, high)`` (m, positive pulls the tendon in),
    ``max_tension`` (N).
    """

    name: str
    theta: tuple[float, ...]
    radius: tuple[float, ...]
    stiffness: float
    displacement_limits: tuple[float, float]
    max_tension: float


@dataclass(frozen=True)
class Gravity:
    enabled: bool = False
    vector: tuple[float, float, float] = (0.0, 0.0, -9.81)


@dataclass(frozen=True)
class BaseMotion:
    """Base rotation and retraction as configuration variables (the Kuntz lab's
    ``enable_rotation`` / ``enable_retraction``).

    Not a rigid placement (that is :class:`BasePose`): *retraction* ``rho`` (m) pulls the robot
    back through its base, so only the arc ``s in [rho, L]`` is exposed, starting at the base
    origin along +z; the tendon routing is evaluated at the absolute arc length, and the tendons
    still end at the tip. *Rotation* ``phi`` (rad) turns the whole exposed shape about the base z
    axis: ``x -> Rz(phi) x``. This is the lab's ``TendonRobot::shape(tau, rotation, retraction)``
    (Kuntz-Lab/interactive-rate-tendons, ``tension_shape(tau, s_start)`` then ``rotate_z``).

    ``rotation_limits`` (rad) and ``retraction_limits`` (m) bound the inputs; the lab samples
    rotations in ``[-pi, pi]`` and retractions in ``[0, L]``; we keep at least one integration
    step exposed (``retraction <= L - step``).
    """

    rotation: bool = False
    retraction: bool = False
    rotation_limits: tuple[float, float] = (-math.pi, math.pi)
    retraction_limits: tuple[float, float] = (0.0, 0.0)

    @property
    def n_extra(self) -> int:
        """Configuration variables beyond the tendons (0, 1 or 2)."""
        return int(self.rotation) + int(self.retraction)


@dataclass(frozen=True)
class HysteresisParams:
    """Play (backlash) operator per tendon plus per-run variation (see robots.hysteresis)."""

    play: float = 0.0005
    play_variation: float = 0.2
    offset_std: float = 0.0001


@dataclass(frozen=True)
class RobotParams:
    name: str
    backbone: Backbone
    disks: Disks
    tendons: tuple[Tendon, ...]
    gravity: Gravity = field(default_factory=Gravity)
    base: BasePose = field(default_factory=BasePose)
    hysteresis: HysteresisParams = field(default_factory=HysteresisParams)
    base_motion: BaseMotion = field(default_factory=BaseMotion)
    #: radius of the robot body for collision checks (m); None: the backbone's outer radius
    collision_radius: float | None = None


# Bounds on the work a robot file may ask for. Every shape solve integrates n_steps = length / step
# steps for every configuration, and the batch solvers hold (batch, n_steps, ...) arrays: a file
# with length = 1e5 m and a 5 mm step (2e7 steps) took 45 s and 8 GB before a MemoryError. The
# paper robot has 40 steps; 20 000 steps (e.g. a 2 m robot at 0.1 mm) is far beyond any tendon robot.
MAX_STEPS = 20_000
MAX_DISKS = 10_000
MAX_TENDONS = 64
MAX_POLY_TERMS = 16


def rpy_to_matrix(rpy) -> np.ndarray:
    """Roll-pitch-yaw (extrinsic x, then y, then z): ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    Parameters
    ----------
    rpy : array_like, shape (3,)
        Roll, pitch, yaw [rad].

    Returns
    -------
    numpy.ndarray
        ``(3, 3)`` rotation matrix.
    """
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


#: top-level tables of a problem file that a robot reader skips (riskplan.planning.problem reads them)
PROBLEM_TABLES = frozenset({"problem", "environment", "voxel_environment"})
NATIVE_KEYS = frozenset(
    {
        "name",
        "backbone",
        "disks",
        "tendons",
        "gravity",
        "base",
        "hysteresis",
        "base_motion",
        "collision_radius",
    }
)


def parse_robot_document(doc: dict, *, default_name: str = "robot") -> RobotParams:
    """Validate a parsed riskplan robot document (the dict of a TOML file, docs/robots.md).

    The tables of a problem file (``[problem]``, ``[environment]``, ``[voxel_environment]``)
    are skipped. Raises :class:`RobotDescriptionError` naming the offending key.
    """
    check_unknown_keys(doc, NATIVE_KEYS | PROBLEM_TABLES, "")
    name = doc.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise RobotDescriptionError(
            "robot description: 'name' must be a non-empty string", key="name"
        )
    backbone = _backbone(field_table(doc, "backbone"))
    disks = _disks(field_table(doc, "disks", required=False), backbone)
    tendons = _tendons(doc.get("tendons"), backbone.length)
    g = field_table(doc, "gravity", required=False)
    check_unknown_keys(g, {"enabled", "vector"}, "gravity")
    enabled = g.get("enabled", False)
    if not isinstance(enabled, bool):
        raise RobotDescriptionError(
            "robot description: 'gravity.enabled' must be true or false", key="gravity.enabled"
        )
    gravity = Gravity(enabled, field_vector(g, "vector", "gravity", 3, default=(0.0, 0.0, -9.81)))
    base = _base_pose(field_table(doc, "base", required=False))
    h = field_table(doc, "hysteresis", required=False)
    check_unknown_keys(h, {"play", "play_variation", "offset_std"}, "hysteresis")
    hyst = HysteresisParams(
        field_number(h, "play", "hysteresis", default=0.0005, nonneg=True),
        field_number(h, "play_variation", "hysteresis", default=0.2, nonneg=True),
        field_number(h, "offset_std", "hysteresis", default=0.0001, nonneg=True),
    )
    motion = _base_motion(field_table(doc, "base_motion", required=False), backbone)
    collision_radius = None
    if "collision_radius" in doc:
        collision_radius = field_number(doc, "collision_radius", "", positive=True)
    return RobotParams(
        name, backbone, disks, tuple(tendons), gravity, base, hyst, motion, collision_radius
    )


def _backbone(b: dict) -> Backbone:
    """``[backbone]``: the rod's geometry and material (the shear modulus from Poisson's
    ratio, 0.3 by default, unless given) and the integration step."""
    check_unknown_keys(
        b,
        {
            "length",
            "outer_radius",
            "inner_radius",
            "youngs_modulus",
            "shear_modulus",
            "poisson_ratio",
            "density",
            "step",
        },
        "backbone",
    )
    length = field_number(b, "length", "backbone", positive=True)
    ro = field_number(b, "outer_radius", "backbone", positive=True)
    ri = field_number(b, "inner_radius", "backbone", default=0.0, nonneg=True)
    if ri >= ro:
        raise RobotDescriptionError(
            f"robot description: 'backbone.inner_radius' ({ri}) must be < outer_radius ({ro})",
            key="backbone.inner_radius",
        )
    E = field_number(b, "youngs_modulus", "backbone", positive=True)
    if "shear_modulus" in b and "poisson_ratio" in b:
        raise RobotDescriptionError(
            "robot description: give either 'backbone.shear_modulus' or 'backbone.poisson_ratio', not both",
            key="backbone.shear_modulus",
        )
    if "shear_modulus" in b:
        G = field_number(b, "shear_modulus", "backbone", positive=True)
    else:
        nu = field_number(b, "poisson_ratio", "backbone", default=0.3)
        if not -1.0 < nu < 0.5:
            raise RobotDescriptionError(
                f"robot description: 'backbone.poisson_ratio' must lie in (-1, 0.5), got {nu}",
                key="backbone.poisson_ratio",
            )
        G = E / (2.0 * (1.0 + nu))
    density = field_number(b, "density", "backbone", default=1000.0, nonneg=True)
    step = field_number(b, "step", "backbone", default=0.005, positive=True)
    if step > length:
        raise RobotDescriptionError(
            f"robot description: 'backbone.step' ({step}) exceeds the length", key="backbone.step"
        )
    if length / step > MAX_STEPS:
        raise RobotDescriptionError(
            f"robot description: length / step = {length:g} / {step:g} = {length / step:.3g} integration steps per shape, more "
            f"than the limit of {MAX_STEPS} (every solve integrates all of them; use a larger 'backbone.step' or a shorter length)",
            key="backbone.step",
        )
    return Backbone(length, ro, ri, E, G, density, step)


def _disks(d: dict, backbone: Backbone) -> Disks:
    """``[disks]``: count and positions (default: evenly spaced, the last at the tip)."""
    length = backbone.length
    check_unknown_keys(d, {"count", "radius", "thickness", "density", "positions"}, "disks")
    count = field_integer(d.get("count", 0), "disks.count", 0, MAX_DISKS)
    if "positions" in d:
        pos = field_vector(d, "positions", "disks", count if count else None)
        if count == 0:
            count = len(pos)
        if count > MAX_DISKS:
            raise RobotDescriptionError(
                f"robot description: {count} disk positions, more than the limit of {MAX_DISKS}",
                key="disks.positions",
            )
    else:
        pos = tuple(length * (k + 1) / count for k in range(count))
    if any(not (0.0 <= p <= length) for p in pos):
        raise RobotDescriptionError(
            "robot description: 'disks.positions' must lie in [0, length]", key="disks.positions"
        )
    return Disks(
        count,
        field_number(
            d, "radius", "disks", default=max(2 * backbone.outer_radius, 0.01), positive=True
        ),
        field_number(d, "thickness", "disks", default=0.002, nonneg=True),
        field_number(d, "density", "disks", default=0.0, nonneg=True),
        pos,
    )


def _tendons(tl, length: float) -> list[Tendon]:
    """``[[tendons]]``: routing polynomials ``theta(s)``, ``r(s) > 0`` on the backbone,
    stiffness, displacement limits and maximal tension of each."""
    if not isinstance(tl, list) or len(tl) == 0:
        raise RobotDescriptionError(
            "robot description: at least one '[[tendons]]' entry is required", key="tendons"
        )
    if len(tl) > MAX_TENDONS:
        raise RobotDescriptionError(
            f"robot description: {len(tl)} tendons, more than the limit of {MAX_TENDONS}",
            key="tendons",
        )
    tendons = []
    for i, t in enumerate(tl):
        path = f"tendons[{i}]"
        if not isinstance(t, dict):
            raise RobotDescriptionError(f"robot description: '{path}' must be a table", key=path)
        check_unknown_keys(
            t, {"name", "theta", "radius", "stiffness", "displacement_limits", "max_tension"}, path
        )
        tname = t.get("name", f"tendon-{i}")
        if not isinstance(tname, str):
            raise RobotDescriptionError(
                f"robot description: '{path}.name' must be a string", key=f"{path}.name"
            )
        theta = field_vector(t, "theta", path, None)
        radius = field_vector(t, "radius", path, None)
        for key, poly in (("theta", theta), ("radius", radius)):
            if not 1 <= len(poly) <= MAX_POLY_TERMS:
                raise RobotDescriptionError(
                    f"robot description: '{path}.{key}' must have 1 to {MAX_POLY_TERMS} polynomial coefficients, got {len(poly)}",
                    key=f"{path}.{key}",
                )
        # r(s) must stay positive along the backbone (checked on a fine grid)
        ss = np.linspace(0.0, length, 201)
        rs = np.polynomial.polynomial.polyval(ss, radius)
        if np.any(rs <= 0):
            raise RobotDescriptionError(
                f"robot description: '{path}.radius' gives r(s) <= 0 on [0, length]",
                key=f"{path}.radius",
            )
        k = field_number(t, "stiffness", path, default=math.inf, positive=True, allow_inf=True)
        lim = field_vector(t, "displacement_limits", path, 2)
        if not lim[0] < lim[1]:
            raise RobotDescriptionError(
                f"robot description: '{path}.displacement_limits' needs low < high, got {lim}",
                key=f"{path}.displacement_limits",
            )
        tmax = field_number(t, "max_tension", path, positive=True)
        tendons.append(Tendon(tname, theta, radius, k, (lim[0], lim[1]), tmax))
    return tendons


def _base_pose(bp: dict) -> BasePose:
    """``[base]``: position (m) and at most one of rpy (rad), a quaternion or a rotation
    matrix (identity by default)."""
    check_unknown_keys(bp, {"position", "rpy", "quaternion", "rotation"}, "base")
    position = field_vector(bp, "position", "base", 3, default=(0.0, 0.0, 0.0))
    given = [k for k in ("rpy", "quaternion", "rotation") if k in bp]
    if len(given) > 1:
        raise RobotDescriptionError(
            f"robot description: give only one of base.rpy/quaternion/rotation, got {given}",
            key=f"base.{given[1]}",
        )
    if "rpy" in bp:
        Rm = rpy_to_matrix(field_vector(bp, "rpy", "base", 3))
    elif "quaternion" in bp:
        q = field_vector(bp, "quaternion", "base", 4)
        if np.linalg.norm(q) < 1e-12:
            raise RobotDescriptionError(
                "robot description: 'base.quaternion' must be non-zero", key="base.quaternion"
            )
        Rm = quaternion_to_matrix(q)
    elif "rotation" in bp:
        rows = bp["rotation"]
        if not isinstance(rows, list) or len(rows) != 3:
            raise RobotDescriptionError(
                "robot description: 'base.rotation' must be a 3x3 list", key="base.rotation"
            )
        Rm = np.array([field_vector({"r": r}, "r", "base.rotation", 3) for r in rows])
        if not np.allclose(Rm.T @ Rm, np.eye(3), atol=1e-6) or np.linalg.det(Rm) < 0:
            raise RobotDescriptionError(
                "robot description: 'base.rotation' must be a rotation matrix", key="base.rotation"
            )
    else:
        Rm = np.eye(3)
    return BasePose(position, tuple(tuple(float(v) for v in row) for row in Rm))


def _base_motion(bm: dict, backbone: Backbone) -> BaseMotion:
    """``[base_motion]``: which base motions the robot has and their limits (retraction
    keeps at least one integration step exposed)."""
    length, step = backbone.length, backbone.step
    check_unknown_keys(
        bm, {"rotation", "retraction", "rotation_limits", "retraction_limits"}, "base_motion"
    )
    flags = {}
    for key in ("rotation", "retraction"):
        flags[key] = bm.get(key, False)
        if not isinstance(flags[key], bool):
            raise RobotDescriptionError(
                f"robot description: 'base_motion.{key}' must be true or false",
                key=f"base_motion.{key}",
            )
    rot_lim = field_vector(bm, "rotation_limits", "base_motion", 2, default=(-math.pi, math.pi))
    ret_lim = field_vector(bm, "retraction_limits", "base_motion", 2, default=(0.0, length - step))
    if not rot_lim[0] < rot_lim[1]:
        raise RobotDescriptionError(
            f"robot description: 'base_motion.rotation_limits' needs low < high, got {rot_lim}",
            key="base_motion.rotation_limits",
        )
    if not (0.0 <= ret_lim[0] < ret_lim[1] <= length - step + 1e-12):
        raise RobotDescriptionError(
            f"robot description: 'base_motion.retraction_limits' must satisfy 0 <= low < high <= "
            f"length - step = {length - step:g} m (at least one integration step stays exposed), got {ret_lim}",
            key="base_motion.retraction_limits",
        )
    return BaseMotion(
        flags["rotation"], flags["retraction"], (rot_lim[0], rot_lim[1]), (ret_lim[0], ret_lim[1])
    )


def params_to_dict(p: RobotParams) -> dict:
    """The TOML document (as a dict) that :func:`~riskplan.robots.description.parse_robot_toml`
    turns back into ``p``."""
    b = p.backbone
    return {
        "name": p.name,
        "backbone": {
            "length": b.length,
            "outer_radius": b.outer_radius,
            "inner_radius": b.inner_radius,
            "youngs_modulus": b.youngs_modulus,
            "shear_modulus": b.shear_modulus,
            "density": b.density,
            "step": b.step,
        },
        "disks": {
            "count": p.disks.count,
            "radius": p.disks.radius,
            "thickness": p.disks.thickness,
            "density": p.disks.density,
            **({"positions": list(p.disks.positions)} if p.disks.count else {}),
        },
        "tendons": [
            {
                "name": t.name,
                "theta": list(t.theta),
                "radius": list(t.radius),
                **({"stiffness": t.stiffness} if math.isfinite(t.stiffness) else {}),
                "displacement_limits": list(t.displacement_limits),
                "max_tension": t.max_tension,
            }
            for t in p.tendons
        ],
        "gravity": {"enabled": p.gravity.enabled, "vector": list(p.gravity.vector)},
        "base": {"position": p.base.position.tolist(), "rotation": p.base.rotation.tolist()},
        "hysteresis": {
            "play": p.hysteresis.play,
            "play_variation": p.hysteresis.play_variation,
            "offset_std": p.hysteresis.offset_std,
        },
        **(
            {
                "base_motion": {
                    "rotation": p.base_motion.rotation,
                    "retraction": p.base_motion.retraction,
                    "rotation_limits": list(p.base_motion.rotation_limits),
                    "retraction_limits": list(p.base_motion.retraction_limits),
                }
            }
            if p.base_motion.n_extra
            else {}
        ),
        **({"collision_radius": p.collision_radius} if p.collision_radius is not None else {}),
    }


def params_to_toml(p: RobotParams) -> str:
    """A robot description as a robot file.

    Parameters
    ----------
    p : RobotParams
        The description.

    Returns
    -------
    str
        TOML text that :func:`~riskplan.robots.description.parse_robot_toml` turns back into
        ``p``.
    """
    import tomli_w

    return tomli_w.dumps(params_to_dict(p))
