"""A planning problem read from a file: robot, start and goal, environment.

Reads the Kuntz lab's problem files unchanged (Kuntz-Lab/Tendon_Robot_Learning, e.g.
``resources/collapse-segmentation/tasks/task-0001.toml``; the C++ reader is
``motion_planning::Problem::from_toml`` in Kuntz-Lab/interactive-rate-tendons) and riskplan's
own robot files with the same tables:

* the robot: any layout :func:`riskplan.robots.load_robot` reads (same file);
* ``[problem]``: ``start``/``goal`` tendon **tensions** (N), or riskplan's
  ``start_displacements``/``goal_displacements`` (m); ``start_rotation``/``goal_rotation`` (rad)
  and ``start_retraction``/``goal_retraction`` (m) where the robot enables them;
  ``min_tension_change`` (N), ``min_rotation_change`` (rad), ``min_retraction_change`` (m) —
  the lab planner's resolution of a configuration-space motion; the lab's
  ``sample_like_sphere`` flag is read and kept. The lab's nested layout keeps ``start``,
  ``goal``, ``min_tension_change`` at the top level (read the same way);
* ``[environment]``: ``[[environment.meshes]] filename`` (relative to the problem file),
  ``[[environment.spheres]] center, radius`` (m), ``[[environment.points]] point`` (m);
* ``[voxel_environment]``: the lab's voxel obstacles (:class:`VoxelEnvironment`).

Configurations follow the lab's order: tendons, then rotation, then retraction
(:meth:`riskplan.robots.TendonRobot.split_configuration`). Start and goal are converted
between tensions and displacements through the robot model (at their own retraction).
Everything is checked when the file is read, before anything is computed or written;
errors name the file and the field (``task.toml: problem.goal[2] = 4.1 N is above
max_tension 3.5 N``).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from riskplan.errors import InvalidInputError, RobotDescriptionError
from riskplan.planning.problem_voxels import VoxelEnvironment

__all__ = ["Problem", "Sphere", "load_problem"]

_PROBLEM_KEYS = {
    "start",
    "goal",
    "start_displacements",
    "goal_displacements",
    "start_rotation",
    "goal_rotation",
    "start_retraction",
    "goal_retraction",
    "min_tension_change",
    "min_rotation_change",
    "min_retraction_change",
    "sample_like_sphere",
}
_ENV_KEYS = {"meshes", "spheres", "points"}
_VOXEL_KEYS = {"filename", "interior_filename", "scaling", "translation", "rotation_quat"}


class ProblemFileError(RobotDescriptionError):
    """A problem file is malformed; the message names the file and ``key`` the field."""


def _err(path, key: str, message: str) -> ProblemFileError:
    where = f"{path}: " if path is not None else ""
    return ProblemFileError(f"{where}{key}: {message}", key=key)


def _unknown(table: dict, allowed: set, prefix: str, path) -> None:
    from riskplan.robots.params import suggest_key

    for k in table:
        if k not in allowed:
            raise _err(path, f"{prefix}{k}", f"unknown key{suggest_key(k, allowed)}")


def _number(table: dict, key: str, prefix: str, path, *, default=None, nonneg=False) -> float:
    if key not in table:
        if default is None:
            raise _err(path, f"{prefix}{key}", "missing")
        return float(default)
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise _err(path, f"{prefix}{key}", f"expected a finite number, got {v!r}")
    if nonneg and v < 0:
        raise _err(path, f"{prefix}{key}", f"expected >= 0, got {v!r}")
    return float(v)


def _vector(table: dict, key: str, prefix: str, path, n: int | None) -> np.ndarray:
    v = table[key]
    if not isinstance(v, list) or not all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v
    ):
        raise _err(path, f"{prefix}{key}", f"expected a list of finite numbers, got {v!r}")
    if n is not None and len(v) != n:
        raise _err(path, f"{prefix}{key}", f"expected {n} entries, got {len(v)}")
    return np.array(v, dtype=np.float64)


@dataclass(frozen=True)
class Sphere:
    """A spherical obstacle: ``center (3,)`` (m, robot frame) and ``radius`` (m)."""

    center: tuple[float, float, float]
    radius: float


# ----------------------------------------------------------------------------- problem
@dataclass(frozen=True, eq=False)
class Problem:
    """A planning problem: a robot, start and goal configurations, and an environment.

    ``start``/``goal`` are ``(n_config,)`` configurations in the lab's order (tendon tensions
    [N], rotation [rad] if enabled, retraction [m] if enabled); ``start_displacements`` /
    ``goal_displacements`` the tendon displacements [m] that hold the same shapes
    (:meth:`TendonRobot.displacements_for_tensions` at their retraction). Meshes are absolute
    paths (a file's relative names resolved against the file's folder).
    """

    robot: object
    start: np.ndarray
    goal: np.ndarray
    start_displacements: np.ndarray
    goal_displacements: np.ndarray
    min_tension_change: float | None = None
    min_rotation_change: float | None = None
    min_retraction_change: float | None = None
    meshes: tuple[Path, ...] = ()
    spheres: tuple[Sphere, ...] = ()
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    voxel_environment: VoxelEnvironment | None = None
    sample_like_sphere: bool | None = None
    path: Path | None = None

    @property
    def n_config(self) -> int:
        return int(self.robot.n_config)

    @property
    def configuration_limits(self) -> np.ndarray:
        """``(n_config, 2)`` limits of tensions [0, max_tension] (N), then rotation and
        retraction: the box a planner searches (the configuration is in tension form)."""
        lim = np.array(self.robot.configuration_limits, dtype=np.float64)
        m = self.robot.n_tendons
        lim[:m, 0] = 0.0
        lim[:m, 1] = self.robot.tension_limits
        return lim

    def interpolate(self, a, b, t) -> np.ndarray:
        """Configurations along the straight motion from ``a`` to ``b``.

        :meth:`TendonRobot.interpolate_configurations`: rotation the short way round.

        Parameters
        ----------
        a, b : array_like, (n_config,)
            End configurations.
        t : float or array_like, (...)
            Fractions of the motion in [0, 1].

        Returns
        -------
        numpy.ndarray, (..., n_config)
        """
        return self.robot.interpolate_configurations(a, b, t)

    def split(self, q):
        """``(tensions, rotation, retraction)`` of a configuration (None where not enabled).

        Parameters
        ----------
        q : array_like, (..., n_config)
            Configurations (N of tension, then rad and m).

        Returns
        -------
        tuple
            ``tensions (..., m)``, ``rotation (...)`` or None, ``retraction (...)`` or None.
        """
        return self.robot.split_configuration(q)

    def shape(self, q):
        """The robot's :class:`~riskplan.robots.RodShape` at a configuration.

        Parameters
        ----------
        q : array_like, (..., n_config)
            Configurations (N of tension, then rad and m).

        Returns
        -------
        RodShape
            The shapes.
        """
        tau, rot, ret = self.split(q)
        if rot is None and ret is None:
            return self.robot.solve_tensions(tau)
        return self.robot.solve_tensions(tau, rotation=rot, retraction=ret)

    def load_meshes(self, *, check_units: bool = True):
        """The environment meshes as one ``trimesh.Trimesh`` (robot frame, m), or None.

        Parameters
        ----------
        check_units : bool
            Refuse a mesh whose bounding box is more than ``MILLIMETRE_FACTOR`` robot lengths across
            (:func:`~riskplan.collision.geometry.check_metre_scale`): its units are most likely
            millimetres where metres are expected.

        Returns
        -------
        trimesh.Trimesh or None
            The meshes concatenated; None without meshes.
        """
        if not self.meshes:
            return None
        import trimesh

        from riskplan.collision.geometry import check_metre_scale

        parts = []
        L = self.robot.params.backbone.length
        for k, mp in enumerate(self.meshes):
            try:
                mesh = trimesh.load_mesh(mp, force="mesh")
            except Exception as exc:
                raise _err(
                    self.path, f"environment.meshes[{k}].filename", f"cannot read {mp} ({exc})"
                ) from exc
            if check_units and len(mesh.vertices):
                try:
                    check_metre_scale(mesh.vertices, L, source=mp.name)
                except InvalidInputError as exc:
                    raise _err(self.path, f"environment.meshes[{k}].filename", str(exc)) from None
            parts.append(mesh)
        return trimesh.util.concatenate(parts) if len(parts) > 1 else parts[0]


def load_problem(path, *, robot=None) -> Problem:
    """Read a problem file (the lab's layouts or riskplan's, see the module docs).

    Everything is checked before anything is computed: the ``[problem]`` table (start and
    goal, the motion resolutions), the ``[environment]`` table and ``[voxel_environment]``.

    Parameters
    ----------
    path : str or path
        The problem file (TOML).
    robot : TendonRobot or str or path, optional
        A robot to use instead of the file's own (for a file that holds only
        ``[problem]``/``[environment]``): a :class:`~riskplan.robots.TendonRobot`, or a name
        or file :func:`~riskplan.robots.load_robot` reads.

    Returns
    -------
    Problem
        The robot, start and goal configurations ``(n_config,)`` (tensions in N, then
        rotation in rad and retraction in m where enabled) with their displacements ``(m,)``
        (m), and the environment.

    Raises
    ------
    ProblemFileError
        (an :class:`~riskplan.errors.InvalidInputError`) naming the file and the field.
    """
    p = Path(path)
    doc = _read_toml(p)
    robot = _problem_robot(p, robot)
    prob, prefix = _problem_table(doc, p)
    configs, disp = {}, {}
    for end in ("start", "goal"):
        configs[end], disp[end] = _end_configuration(prob, end, prefix, p, robot)
    changes = {
        k: (_number(prob, k, prefix, p, nonneg=True) if k in prob else None)
        for k in ("min_tension_change", "min_rotation_change", "min_retraction_change")
    }
    sample_like_sphere = prob.get("sample_like_sphere")
    if sample_like_sphere is not None and not isinstance(sample_like_sphere, bool):
        raise _err(p, f"{prefix}sample_like_sphere", "must be true or false")
    env = doc.get("environment", {})
    if not isinstance(env, dict):
        raise _err(p, "environment", "must be a table")
    _unknown(env, _ENV_KEYS, "environment.", p)
    return Problem(
        robot=robot,
        start=configs["start"],
        goal=configs["goal"],
        start_displacements=disp["start"],
        goal_displacements=disp["goal"],
        min_tension_change=changes["min_tension_change"],
        min_rotation_change=changes["min_rotation_change"],
        min_retraction_change=changes["min_retraction_change"],
        meshes=_meshes(env, p),
        spheres=_spheres(env, p),
        points=_points(env, p),
        voxel_environment=_voxel_environment(doc, p),
        sample_like_sphere=sample_like_sphere,
        path=p.resolve(),
    )


def _read_toml(p: Path) -> dict:
    from riskplan.robots.description import read_robot_text

    try:
        return tomllib.loads(read_robot_text(p))
    except tomllib.TOMLDecodeError as exc:
        raise ProblemFileError(f"{p}: not valid TOML ({exc})") from exc


def _problem_robot(p: Path, robot):
    """The file's own robot, or ``robot`` (loaded if a name or path)."""
    from riskplan.robots import TendonRobot, load_robot

    if robot is None:
        try:
            return load_robot(p)
        except RobotDescriptionError as exc:
            raise ProblemFileError(f"{p}: {exc}", key=exc.key) from None
    return robot if isinstance(robot, TendonRobot) else load_robot(robot)


def _problem_table(doc: dict, p: Path) -> tuple[dict, str]:
    """The problem's keys and the prefix their errors carry (``"problem."``, or ``""`` for
    the lab's nested layout, which keeps them at the top level)."""
    if "problem" not in doc:
        return {k: doc[k] for k in _PROBLEM_KEYS if k in doc}, ""
    prob = doc["problem"]
    if not isinstance(prob, dict):
        raise _err(p, "problem", "must be a table")
    _unknown(prob, _PROBLEM_KEYS, "problem.", p)
    return prob, "problem."


def _end_configuration(prob, end: str, prefix: str, p, robot) -> tuple[np.ndarray, np.ndarray]:
    """The start or goal (``end``) as a configuration ``(n_config,)`` (tensions, then the
    base motion) and displacements ``(m,)``, from the tensions or the displacements given,
    converted through the robot model and checked against the robot's limits."""
    m = robot.n_tendons
    given = [k for k in (end, f"{end}_displacements") if k in prob]
    if len(given) != 1:
        raise _err(
            p,
            f"{prefix}{end}",
            f"give exactly one of '{end}' (tensions, N) and '{end}_displacements' (m)"
            + (", got both" if len(given) == 2 else ""),
        )
    vec = _vector(prob, given[0], prefix, p, m)
    extra = _base_motion(prob, end, prefix, p, robot.base_motion)
    ret = extra[-1] if robot.base_motion.retraction else None
    if given[0] == end:
        tmax = robot.tension_limits
        for j in range(m):
            if not 0.0 <= vec[j] <= tmax[j]:
                raise _err(
                    p,
                    f"{prefix}{end}[{j}]",
                    f"{vec[j]} N is outside the tension limits [0, {tmax[j]:g}] N "
                    f"(max_tension of tendon {j})",
                )
        return np.concatenate([vec, extra]), robot.displacements_for_tensions(vec, retraction=ret)
    lim = robot.displacement_limits
    for j in range(m):
        if not lim[j, 0] <= vec[j] <= lim[j, 1]:
            raise _err(
                p,
                f"{prefix}{end}_displacements[{j}]",
                f"{vec[j]} m is outside the displacement limits [{lim[j, 0]:g}, {lim[j, 1]:g}] m",
            )
    tau = robot.tensions_for_displacements(vec, retraction=ret)
    over = np.flatnonzero(tau > robot.tension_limits * (1 + 1e-9))
    if over.size:
        j = int(over[0])
        raise _err(
            p,
            f"{prefix}{end}_displacements[{j}]",
            f"needs {tau[j]:.4g} N on tendon {j}, above its max_tension "
            f"{robot.tension_limits[j]:g} N",
        )
    return np.concatenate([tau, extra]), vec


def _base_motion(prob, end: str, prefix: str, p, bm) -> list[float]:
    """``end``'s base rotation (rad) and retraction (m), those the robot enables, in that
    order; required where enabled, refused (unless zero) where not."""
    extra = []
    for var, enabled, lim, unit in (
        ("rotation", bm.rotation, bm.rotation_limits, "rad"),
        ("retraction", bm.retraction, bm.retraction_limits, "m"),
    ):
        key = f"{end}_{var}"
        if not enabled:
            if key in prob and float(prob[key]) != 0.0:
                raise _err(p, f"{prefix}{key}", f"the robot has no base {var}")
            continue
        if key not in prob:
            raise _err(p, f"{prefix}{key}", f"required: the robot enables base {var}")
        v = _number(prob, key, prefix, p)
        if not lim[0] <= v <= lim[1]:
            raise _err(
                p, f"{prefix}{key}", f"{v} {unit} is outside the limits [{lim[0]:g}, {lim[1]:g}]"
            )
        extra.append(v)
    return extra


def _meshes(env: dict, p: Path) -> tuple[Path, ...]:
    """``[[environment.meshes]]``: existing files, relative to the problem file."""
    meshes = []
    for k, t in enumerate(env.get("meshes", [])):
        key = f"environment.meshes[{k}]"
        if not isinstance(t, dict):
            raise _err(p, key, "must be a table")
        _unknown(t, {"filename"}, f"{key}.", p)
        if not isinstance(t.get("filename"), str):
            raise _err(p, f"{key}.filename", "expected a file name (string)")
        mp = Path(t["filename"])
        mp = mp if mp.is_absolute() else (p.parent / mp)
        if not mp.is_file():
            raise _err(p, f"{key}.filename", f"no such file: {mp}")
        meshes.append(mp.resolve())
    return tuple(meshes)


def _spheres(env: dict, p: Path) -> tuple[Sphere, ...]:
    """``[[environment.spheres]]``: centre (m) and a positive radius (m)."""
    spheres = []
    for k, t in enumerate(env.get("spheres", [])):
        key = f"environment.spheres[{k}]"
        if isinstance(t, dict) and isinstance(t.get("sphere"), dict):
            t = t["sphere"]  # the lab accepts the sphere's own table inside
        if not isinstance(t, dict):
            raise _err(p, key, "must be a table")
        _unknown(t, {"center", "radius"}, f"{key}.", p)
        if "center" not in t:
            raise _err(p, f"{key}.center", "missing")
        c = _vector(t, "center", f"{key}.", p, 3)
        r = _number(t, "radius", f"{key}.", p)
        if not r > 0:
            raise _err(p, f"{key}.radius", f"expected > 0, got {r}")
        spheres.append(Sphere(tuple(float(v) for v in c), r))
    return tuple(spheres)


def _points(env: dict, p: Path) -> np.ndarray:
    """``[[environment.points]]``: obstacle points ``(n, 3)`` (m)."""
    pts = []
    for k, t in enumerate(env.get("points", [])):
        key = f"environment.points[{k}]"
        if not isinstance(t, dict) or "point" not in t:
            raise _err(p, key, "expected a table with 'point'")
        _unknown(t, {"point"}, f"{key}.", p)
        pts.append(_vector(t, "point", f"{key}.", p, 3))
    return np.array(pts, dtype=np.float64).reshape(-1, 3)


def _voxel_environment(doc: dict, p: Path) -> VoxelEnvironment | None:
    """``[voxel_environment]``: the voxel file(s), relative to the problem file, and their
    placement (scaling, translation in m, rotation quaternion)."""
    if "voxel_environment" not in doc:
        return None
    v = doc["voxel_environment"]
    if not isinstance(v, dict):
        raise _err(p, "voxel_environment", "must be a table")
    _unknown(v, _VOXEL_KEYS, "voxel_environment.", p)
    files = {}
    for k in ("filename", "interior_filename"):
        if k in v:
            if not isinstance(v[k], str):
                raise _err(p, f"voxel_environment.{k}", "expected a file name (string)")
            f = Path(v[k])
            files[k] = (f if f.is_absolute() else (p.parent / f)).resolve()
    if "filename" not in files:
        raise _err(p, "voxel_environment.filename", "missing (voxels stored inline are not read)")
    q = _vector(v, "rotation_quat", "voxel_environment.", p, 4) if "rotation_quat" in v else None
    if q is not None and np.linalg.norm(q) < 1e-12:
        raise _err(p, "voxel_environment.rotation_quat", "must be non-zero")
    tr = _vector(v, "translation", "voxel_environment.", p, 3) if "translation" in v else None
    scaling = _number(v, "scaling", "voxel_environment.", p, default=1.0)
    if not scaling > 0:
        raise _err(p, "voxel_environment.scaling", f"expected > 0, got {scaling}")
    return VoxelEnvironment(
        files["filename"],
        scaling,
        tuple(float(x) for x in (tr if tr is not None else (0.0, 0.0, 0.0))),
        tuple(float(x) for x in (q if q is not None else (1.0, 0.0, 0.0, 0.0))),
        files.get("interior_filename"),
    )
