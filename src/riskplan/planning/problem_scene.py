"""The planner's scene and configurations of a problem (:mod:`riskplan.planning.problem`) or of
command-line options: :func:`problem_environment` (meshes, spheres, points, voxels; a
:class:`WallEnvironment` where a surface is open), :func:`problem_configurations` (start and goal
as model inputs), :func:`problem_from_options`. :func:`riskplan.planning.robot_plan.plan_robot`
plans in them (its module docs, "Scenes")."""

from __future__ import annotations

import logging

import numpy as np

from riskplan._validation import as_array
from riskplan.collision import Environment
from riskplan.errors import InvalidInputError

log = logging.getLogger(__name__)

__all__ = [
    "VOXEL_POLICIES",
    "WallEnvironment",
    "problem_configurations",
    "problem_environment",
    "problem_from_options",
]


class WallEnvironment(Environment):
    """Surfaces as walls: meshes that need not be closed (:mod:`riskplan.planning.robot_plan`,
    "Scenes").

    ``solid``: an :class:`Environment` of closed obstacles among them (spheres, closed meshes)
    whose inside counts as in collision; ``contains`` is its containment (False everywhere
    without one: a surface has no inside). ``crossing_check``: motions are checked for component
    means crossing a surface (:meth:`MeanValidity.motions`).
    """

    crossing_check = True

    def __init__(self, vertices, faces, face_obstacle=None, names=None, *, solid=None):
        super().__init__(vertices, faces, face_obstacle, names, validate=False)
        V = self.vertices
        if not np.all(np.isfinite(V)):
            raise InvalidInputError("vertices: contain NaN or inf")
        self.solid = solid

    def winding_number(self, points) -> np.ndarray:
        P = np.asarray(points, dtype=np.float64)
        if self.solid is None:
            return np.zeros(P.shape[:-1], dtype=np.int64)
        return self.solid.winding_number(P)

    def contains(self, points) -> np.ndarray:
        return self.winding_number(points) > 0


def _icosphere(center, radius):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=3, radius=float(radius))
    m.apply_translation(np.asarray(center, dtype=np.float64))
    return m


#: when the planner uses a problem's ``[voxel_environment]``: ``auto`` = when the problem gives
#: no mesh (the lab's task files give the same anatomy as an STL and as voxels; the voxel
#: surface is about 130 times the STL's triangles), ``on``, ``off``
VOXEL_POLICIES = ("auto", "on", "off")


def _concat(envs, names):
    """One :class:`Environment` of solid obstacles from several (their obstacles in order)."""
    V, F, owner, off, k = [], [], [], 0, 0
    for e in envs:
        V.append(e.vertices)
        F.append(e.faces + off)
        owner.append(e.face_obstacle + k)
        off += len(e.vertices)
        k += e.n_obstacles
    return Environment(
        np.vstack(V), np.vstack(F), np.concatenate(owner), list(names), validate=False
    )


def problem_environment(problem, *, check_units: bool = True, voxels: str = "auto"):
    """The planner's scene of a :class:`~riskplan.planning.problem.Problem` (robot frame).

    * Meshes (``[environment.meshes]``, units checked against the robot's length) and spheres
      (``[environment.spheres]``, as closed icospheres).
    * Points (``[[environment.points]]``): a point has no volume, so it is an obstacle for the
      robot's body, not for its backbone: a sphere of the robot's ``collision_radius`` (the
      lab's ``tendon_robot.radius``; else the backbone's outer radius) about the point, the
      set of backbone positions at which the body touches it.
    * Voxels (``[voxel_environment]``, per ``voxels``: :data:`VOXEL_POLICIES`): the union of the
      occupied cells, its exact boundary (:func:`riskplan.collision.voxels.voxel_environment`),
      moved into the robot frame (:meth:`VoxelEnvironment.voxel_to_robot`).

    All closed: an :class:`Environment` of solid obstacles. Any mesh open (the lab's anatomy
    has an opening where the robot enters): a :class:`WallEnvironment` of all surfaces, the
    closed ones solid. A problem with no obstacle the planner uses is refused. Raises
    :class:`InvalidInputError` naming the file and field.

    Parameters
    ----------
    problem : Problem
        The planning problem.
    check_units : bool
        Check the meshes' units against the robot's length.
    voxels : str
        Voxel policy (:data:`VOXEL_POLICIES`).

    Returns
    -------
    Environment or WallEnvironment
        The scene in the robot frame.
    """
    import trimesh

    from riskplan.collision.geometry import check_closed_mesh

    where = f"{problem.path}: " if problem.path is not None else ""
    if voxels not in VOXEL_POLICIES:
        raise InvalidInputError(f"voxels: expected one of {VOXEL_POLICIES}, got {voxels!r}")
    use_voxels = problem.voxel_environment is not None and (
        voxels == "on" or (voxels == "auto" and not problem.meshes)
    )
    if voxels == "on" and problem.voxel_environment is None:
        raise InvalidInputError(f"{where}voxel_environment: none in the problem (voxels='on')")
    if not problem.meshes and not problem.spheres and not len(problem.points) and not use_voxels:
        raise InvalidInputError(
            f"{where}environment: no meshes, spheres, points or voxels; the planner needs "
            "obstacles ([[environment.meshes]] filename, [[environment.spheres]], "
            "[[environment.points]] or [voxel_environment])"
        )
    parts, names = [], []
    if problem.meshes:
        problem.load_meshes(check_units=check_units)  # the units check, naming the field
        for mp in problem.meshes:
            m = trimesh.load_mesh(mp, force="mesh", process=True)
            parts.append(m)
            names.append(mp.stem)
    for k, s in enumerate(problem.spheres):
        parts.append(_icosphere(s.center, s.radius))
        names.append(f"sphere{k}")
    if len(problem.points):
        p = problem.robot.params
        r = p.collision_radius if p.collision_radius is not None else p.backbone.outer_radius
        for k, pt in enumerate(np.asarray(problem.points, dtype=np.float64).reshape(-1, 3)):
            parts.append(_icosphere(pt, r))
            names.append(f"point{k}")
    extra = [_voxel_part(problem, where, check_units)] if use_voxels else []
    closed = []
    for m in parts:
        try:
            check_closed_mesh(np.asarray(m.vertices), np.asarray(m.faces), "mesh")
            closed.append(True)
        except InvalidInputError:
            closed.append(False)
    if all(closed):
        envs = ([Environment.from_meshes(parts, names=names)] if parts else []) + extra
        return envs[0] if len(envs) == 1 else _concat(envs, names + ["voxels"] * len(extra))
    solid_parts = [(m, n) for m, n, c in zip(parts, names, closed) if c]
    solid_envs = (
        [Environment.from_meshes([m for m, _ in solid_parts], names=[n for _, n in solid_parts])]
        if solid_parts
        else []
    ) + extra
    solid_names = [n for _, n in solid_parts] + ["voxels"] * len(extra)
    solid = (
        None
        if not solid_envs
        else (solid_envs[0] if len(solid_envs) == 1 else _concat(solid_envs, solid_names))
    )
    V, F, owner, off = [], [], [], 0
    for i, m in enumerate(parts):
        V.append(np.asarray(m.vertices, dtype=np.float64))
        F.append(np.asarray(m.faces, dtype=np.int64) + off)
        owner.append(np.full(len(m.faces), i))
        off += len(m.vertices)
    for j, e in enumerate(extra):
        V.append(e.vertices)
        F.append(e.faces + off)
        owner.append(np.full(len(e.faces), len(parts) + j))
        off += len(e.vertices)
    log.info("open surfaces in the scene (%s): planning with walls", names)
    all_names = names + ["voxels"] * len(extra)
    return WallEnvironment(
        np.vstack(V), np.vstack(F), np.concatenate(owner), all_names, solid=solid
    )


def _voxel_part(problem, where: str, check_units: bool):
    """The environment of ``problem``'s occupied voxels (robot frame) for
    :func:`problem_environment`; its vertices' scale checked against the robot's length."""
    from riskplan.collision.voxels import voxel_environment

    ve = problem.voxel_environment
    grid = ve.load()
    if len(grid.occupied) == 0:
        raise InvalidInputError(f"{where}voxel_environment: the voxel file has no occupied cell")
    env = voxel_environment(
        grid.occupied, grid.limits[:, 0], grid.spacing, transform=ve.voxel_to_robot
    )
    if check_units:
        from riskplan.collision.geometry import check_metre_scale

        try:
            check_metre_scale(env.vertices, problem.robot.params.backbone.length, source="voxels")
        except InvalidInputError as exc:
            raise InvalidInputError(f"{where}voxel_environment.filename: {exc}") from None
    return env


def problem_configurations(problem) -> tuple[np.ndarray, np.ndarray]:
    """Start and goal of ``problem`` as model inputs ``(n_config,)``: tendon displacements
    (converted from the file's tensions through the robot model), then rotation and retraction.

    Parameters
    ----------
    problem : Problem
        The planning problem.

    Returns
    -------
    tuple of numpy.ndarray
        ``(start, goal)``, each ``(n_config,)``.
    """
    m = problem.robot.n_tendons
    return tuple(
        np.concatenate([np.asarray(d, dtype=np.float64), np.asarray(q[m:], dtype=np.float64)])
        for d, q in (
            (problem.start_displacements, problem.start),
            (problem.goal_displacements, problem.goal),
        )
    )


def problem_from_options(robot, env, start, goal):
    """A :class:`~riskplan.planning.problem.Problem` from a robot (name, file or
    :class:`~riskplan.robots.TendonRobot`), a mesh file (robot base frame, m) and start/goal in
    tension form, each ``"T1,...,Tm[,rotation][,retraction]"`` or an ``(n_config,)`` array
    (``goal`` may be ``None`` for a tip target). Checked like a problem file: tension,
    rotation and retraction limits, the mesh present; errors name the option.

    Parameters
    ----------
    robot : str, pathlib.Path or TendonRobot
        A packaged robot's name, a robot file or a robot.
    env : str or pathlib.Path
        The mesh file.
    start : str or array_like
        Start configuration, tension form.
    goal : str, array_like or None
        Goal configuration, tension form; None for a tip target.

    Returns
    -------
    Problem
        The checked problem.
    """
    from pathlib import Path

    from riskplan.parsing import parse_numbers
    from riskplan.planning.problem import Problem
    from riskplan.robots import load_robot

    rob = load_robot(robot)
    mesh = Path(env)
    if not mesh.is_file():
        raise InvalidInputError(f"--env: no such file: {mesh}")
    q = {}
    for name, spec in (("start", start), ("goal", goal)):
        if spec is None:
            continue
        v = (
            parse_numbers(spec, f"--{name}", count=rob.n_config)
            if isinstance(spec, str)
            else as_array(spec, name, shape=(rob.n_config,))
        )
        try:
            d = rob.configuration_to_displacements(v)
        except InvalidInputError as exc:
            raise InvalidInputError(
                f"--{name}: {exc} (robot {rob.name!r}: max_tension {rob.tension_limits.tolist()} N)"
            ) from None
        q[name] = (np.asarray(v, dtype=np.float64), d[: rob.n_tendons])
    if "goal" not in q:  # a tip target: the goal configuration is found by the planner
        q["goal"] = q["start"]
    return Problem(
        robot=rob,
        start=q["start"][0],
        goal=q["goal"][0],
        start_displacements=q["start"][1],
        goal_displacements=q["goal"][1],
        meshes=(mesh.resolve(),),
    )
