"""Does a planned trajectory hold on the robot? Monte Carlo execution on the simulated robot.

The MDN paper (section V) plans with the eq.-10 bound of the learned mixtures and stops there.
This module checks a trajectory of tendon displacements ``(T, m)`` against the physics that
made the training data (:mod:`riskplan.datasets.protocol`, :mod:`riskplan.datasets.generate`):

Execution protocol (one run)
    * a random start, uniform within the displacement limits
      (:func:`~riskplan.datasets.protocol.random_starts`), at rest there (no lag);
    * this run's transmission variation — play widths ``b_i`` and zero offsets ``o_i`` —
      drawn once (:meth:`~riskplan.robots.hysteresis.HysteresisModel.sample_run`), exactly as
      one data-collection run draws them;
    * the actuators move in straight lines start -> ``d_0`` -> ``d_1`` -> ... -> ``d_{T-1}``
      through the play operator (:func:`~riskplan.robots.hysteresis.play_operator`); the
      robot receives ``clip(e_t + o, limits)`` at configuration ``t``. Each tendon's command is
      monotone on a straight segment, so the operator's value at a segment's end depends on
      its end points only: feeding the configurations themselves is exact;
    * the Cosserat shape at every configuration (``robot.solve_displacements``), in the
      robot's base frame (:func:`~riskplan.datasets.generate.to_base_frame`).

Collisions are counted at the ``T`` configurations of the trajectory (the states eq. 10 runs
over), not on the way from the random start to ``d_0`` (not part of the plan).

Run ``i`` uses ``spawn_seeds(seed, n)[i]`` split into (start draw, transmission variation),
so a result depends on ``(robot, trajectory, seed, n)`` only, whatever the backend or chunking.

Body-in-obstacle test
    The body is the backbone swept by a ball of radius ``r`` (a tube closed by hemispheres).
    Default ``r`` = the robot description's ``collision_radius`` where it gives one (the Kuntz
    lab's ``tendon_robot.radius``: their robots are rods without separator disks, 3 mm for the
    task robot), else the separator-disk radius of the point-cloud geometry
    (:class:`~riskplan.robots.geometry.BodyGeometry`; 10 mm for the ``paper`` robot): the
    outer radius of the body the cameras see and the MDN learned, and the same 1 cm as
    :func:`~riskplan.kinematics.robot_mixture.robot_mixture`. The tube contains the 3 mm
    backbone and every disk whatever its orientation, so the test is conservative: between
    disks the real body is thinner, and contacts that only the envelope makes are counted
    (pass ``radius=`` the backbone radius for the other extreme, or ``body="disks"`` for the
    backbone tube plus the disks themselves,
    :func:`~riskplan.planning.clearance.disk_clearance`). The tube enters an obstacle
    iff ``min_s sd(x(s)) < r`` for the environment's signed distance ``sd`` (negative inside).
    ``sd`` is evaluated at the backbone stations; since ``sd`` is 1-Lipschitz, a chord of
    length ``h`` between stations with distances ``a, b`` has ``sd >= (a + b - h) / 2`` and
    is refined (``sd`` at points ``resolution`` apart) only where that lower bound is below
    ``r``. Penetrations shallower than ``resolution / 2`` (0.25 mm by default) can be missed;
    the chord-to-curve distance between 5 mm stations, ``h^2 kappa / 8``, is below 0.1 mm up to
    a curvature of 30 1/m (a straight tendon at its 9.73 N limit bends the ``paper`` robot by
    about 13 1/m). A hemisphere of the tube also covers ``r`` behind the base (the mount).
"""

from __future__ import annotations

import functools
import hashlib
import logging
from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_array, check_count, check_range
from riskplan.collision import (
    Environment,
    MonteCarloEstimate,
    binomial_interval,
    mixture_bound,
    monte_carlo_probability,
    monte_carlo_trajectory,
)
from riskplan.collision.environment import check_environment
from riskplan.collision.trajectory import trajectory_bound
from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import as_numpy_mixture
from riskplan.parallel import BACKENDS, map_tasks, spawn_seeds
from riskplan.planning._validate_report import (  # noqa: F401 - their home before the split
    endpoint_warnings,
    validation_markdown,
)
from riskplan.planning.clearance import RESOLUTION, disk_clearance, tube_clearance

log = logging.getLogger(__name__)

__all__ = [
    "MixtureMonteCarlo",
    "RobotMonteCarlo",
    "default_radius",
    "execute_on_robot",
    "mixture_monte_carlo",
    "simulate_executions",
    "validation_markdown",
    "validation_table",
]

# executions per parallel task
CHUNK = 25
BODIES = ("tube", "disks")


@dataclass(frozen=True)
class RobotMonteCarlo:
    """Executions of one trajectory on the simulated robot.

    Attributes
    ----------
    trajectory: estimate of ``P(the body enters an obstacle at some configuration)``, shape ``()``.
    per_configuration: estimates per configuration, shape ``(T,)``.
    clearance: ``(n, T)`` smallest signed distance of the body surface to the obstacles [m]
        per run and configuration (negative: inside; see :func:`tube_clearance`).
    radius: tube radius used [m].
    body: ``"tube"`` or ``"disks"`` (:func:`execute_on_robot`).
    seed, n: the seed and the number of executions.
    """

    trajectory: MonteCarloEstimate
    per_configuration: MonteCarloEstimate
    clearance: np.ndarray
    radius: float
    seed: int
    n: int
    body: str = "tube"


@dataclass(frozen=True)
class MixtureMonteCarlo:
    """Monte Carlo of the predicted mixtures of a trajectory: ``trajectory`` (shape ``()``,
    one independent draw per configuration and trial) and ``per_configuration`` (``(T,)``)."""

    trajectory: MonteCarloEstimate
    per_configuration: MonteCarloEstimate


def _estimate(hits, n: int, confidence: float) -> MonteCarloEstimate:
    hits = np.asarray(hits, dtype=np.int64)
    low, high = binomial_interval(hits, n, confidence, "wilson")
    return MonteCarloEstimate(
        hits / n, np.asarray(low), np.asarray(high), hits, n, confidence, "wilson"
    )


def _check_seed(seed) -> int:
    return check_count(seed, "seed", 0)


def _as_robot(robot):
    from riskplan.robots import load_robot

    return load_robot(robot)


def _check_trajectory(trajectory, robot) -> np.ndarray:
    m, nc = robot.n_tendons, robot.n_config
    traj = as_array(trajectory, "trajectory", min_ndim=2)
    if traj.ndim != 2 or traj.shape[1] not in (m, nc) or traj.shape[0] < 1:
        what = f"(T, {m})" if nc == m else f"(T, {m}) or (T, {nc}) with base rotation/retraction"
        raise InvalidInputError(
            f"trajectory: expected shape {what} with T >= 1 for robot {robot.name!r} ({m} tendons), got {traj.shape}"
        )
    lim = np.asarray(
        robot.displacement_limits if traj.shape[1] == m else robot.configuration_limits,
        dtype=np.float64,
    )
    check_range(traj, "trajectory", low=lim[:, 0], high=lim[:, 1])
    return traj


def default_radius(robot) -> float:
    """Outer body radius of ``robot`` [m]: the ``collision_radius`` its description gives (the
    Kuntz lab's ``tendon_robot.radius``, a robot with no separator disks), else the
    separator-disk radius of its point-cloud geometry.

    Parameters
    ----------
    robot : TendonRobot
        The robot.

    Returns
    -------
    float
        The radius [m].
    """
    r = getattr(robot.params, "collision_radius", None)
    if r is not None:
        return float(r)
    from riskplan.robots.geometry import BodyGeometry

    return float(BodyGeometry.from_params(robot.params).disk_radius)


def simulate_executions(robot, trajectory, seeds, *, return_frames: bool = False):
    """Backbones of the robot along ``trajectory (T, m)`` for runs seeded by ``seeds`` (length ``B``).

    Protocol in the module docstring. A robot with base rotation/retraction takes
    ``(T, n_config)`` configurations (tendons, then rotation, then retraction): the tendons go
    through the play operator as above, the base arrives as commanded (as in the data-set
    protocol, :func:`riskplan.datasets.generate.simulate_target`). Inputs are trusted
    (validated by :func:`execute_on_robot`).

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    trajectory : array_like, shape (T, m) or (T, n_config)
        Commanded configurations.
    seeds : sequence of int
        One seed per execution (``B``).
    return_frames : bool
        Also return the body frames.

    Returns
    -------
    numpy.ndarray or tuple of numpy.ndarray
        Backbone positions ``(B, T, n, 3)`` [m], robot base frame; with ``return_frames``
        also the frames ``(B, T, n, 3, 3)``.
    """
    from riskplan.datasets.generate import to_base_frame
    from riskplan.planning.executions import execution_displacements

    q = np.asarray(trajectory, dtype=np.float64)
    rot = ret = None
    if q.shape[1] != robot.n_tendons:
        traj, rot, ret = robot.split_configuration(q, validate=False)
    else:
        traj = q
    eff = execution_displacements(robot, traj, seeds)
    B, T, m = eff.shape
    # configurations near the corners of the displacement box need more than max_tension; the
    # solver warns per call, which would flood a long run (the data generator does the same)
    rlog = logging.getLogger("riskplan.robots.robot")
    level = rlog.level
    rlog.setLevel(logging.ERROR)
    base = {}
    if rot is not None:
        base["rotation"] = np.tile(rot, B)  # run-major like eff.reshape(B * T, m)
    if ret is not None:
        base["retraction"] = np.tile(ret, B)
    try:
        shape = robot.solve_displacements(eff.reshape(B * T, m), validate=False, **base)
    finally:
        rlog.setLevel(level)
    P, R = to_base_frame(robot, shape.positions, shape.rotations)
    P = P.reshape(B, T, P.shape[-2], 3)
    if return_frames:
        return P, R.reshape(B, T, P.shape[-2], 3, 3)
    return P


def _task(item):
    robot_toml, traj, env_key, env, body, radius, resolution, seeds = item
    robot = _robot(robot_toml)
    # one Environment (and its search structures) per worker process, not per task
    env = _ENVIRONMENTS.setdefault(env_key, env)
    if len(_ENVIRONMENTS) > 4:
        _ENVIRONMENTS.pop(next(iter(_ENVIRONMENTS)))
    if body == "tube":
        P = simulate_executions(robot, traj, seeds)
        return tube_clearance(env, P, radius, resolution=resolution)  # (B, T)
    P, R = simulate_executions(robot, traj, seeds, return_frames=True)
    geom = _geometry(robot_toml)
    tube = tube_clearance(env, P, radius, resolution=resolution)
    return np.minimum(tube, disk_clearance(env, robot.s, P, R, geom, resolution=2 * resolution))


@functools.lru_cache(maxsize=4)
def _geometry(text: str):
    from riskplan.robots.geometry import BodyGeometry

    return BodyGeometry.from_params(_robot(text).params)


_ENVIRONMENTS: dict = {}


def _robot(text: str):
    from riskplan.robots import cached_robot

    return cached_robot(text)


def execute_on_robot(
    robot,
    trajectory,
    environment: Environment,
    n: int = 1000,
    seed: int = 0,
    *,
    body: str = "tube",
    radius: float | None = None,
    resolution: float = RESOLUTION,
    confidence: float = 0.95,
    backend: str = "local",
    workers: int | None = None,
    chunk: int = CHUNK,
) -> RobotMonteCarlo:
    """Execute ``trajectory`` ``n`` times on the simulated robot and count body collisions.

    Parameters
    ----------
    robot : TendonRobot or str or path
        The robot, or a robot name/path (``"paper"``).
    trajectory : array_like, (T, m) or (T, n_config)
        Commanded tendon displacements [m] within the robot's limits, or configurations of a
        robot with base rotation/retraction.
    environment : Environment
        3-D obstacles in the robot's base frame (e.g. ``build_chest(seed).base_environment``).
    n, seed : int
        Number of executions and their seed (module docstring: protocol and seeding).
    body : str
        ``"tube"`` (default): the backbone swept by a ball of ``radius`` (module docstring);
        ``"disks"``: the point-cloud geometry itself, the backbone tube of the backbone radius
        (3 mm) plus the separator disks (:func:`disk_clearance`).
    radius : float, optional
        Tube radius [m]; default the disk radius of the point-cloud geometry (10 mm) for
        ``"tube"``, the backbone radius for ``"disks"``.
    resolution : float
        Sample spacing on refined backbone chords [m] (:func:`tube_clearance`).
    confidence : float
        Two-sided confidence of the Wilson intervals.
    backend, workers, chunk
        :func:`riskplan.parallel.map_tasks` over chunks of ``chunk`` runs; the result does not
        depend on them.

    Returns
    -------
    RobotMonteCarlo
        ``P(exists t: body in an obstacle)`` with a Wilson interval at ``confidence``, the
        per-configuration rates, and the clearances ``(n, T)``.
    """
    robot = _as_robot(robot)
    traj = _check_trajectory(trajectory, robot)
    env = check_environment(environment, dim=3)
    n = check_count(n, "n", 1)
    seed = _check_seed(seed)
    chunk = check_count(chunk, "chunk", 1)
    if backend not in BACKENDS:
        raise InvalidInputError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    if not 0 < confidence < 1:
        raise InvalidInputError(f"confidence: expected in (0, 1), got {confidence!r}")
    if body not in BODIES:
        raise InvalidInputError(f"body: expected one of {BODIES}, got {body!r}")
    if radius is None:
        r = (
            default_radius(robot)
            if body == "tube"
            else _geometry(robot.toml_text()).backbone_radius
        )
    else:
        r = float(radius)
    if not (np.isfinite(r) and r >= 0):
        raise InvalidInputError(f"radius: expected a finite length >= 0, got {radius!r}")
    if not (np.isfinite(resolution) and resolution > 0):
        raise InvalidInputError(f"resolution: expected a positive length, got {resolution!r}")
    seeds = spawn_seeds(seed, n)
    # a fresh copy without cached search structures travels to the workers (they do not pickle)
    env_copy = (
        env
        if backend == "serial"
        else Environment(env.vertices, env.faces, env.face_obstacle, env.names, validate=False)
    )
    h = hashlib.sha256()
    for a in (env.vertices, env.faces, env.face_obstacle):
        h.update(np.ascontiguousarray(a).tobytes())
    toml = robot.toml_text()
    items = [
        (toml, traj, h.hexdigest(), env_copy, body, r, resolution, seeds[k : k + chunk])
        for k in range(0, n, chunk)
    ]
    parts = map_tasks(_task, items, backend=backend, workers=workers, chunksize=1)
    clearance = np.concatenate(parts, axis=0)  # (n, T)
    hit = clearance < 0
    return RobotMonteCarlo(
        trajectory=_estimate(hit.any(axis=1).sum(), n, confidence),
        per_configuration=_estimate(hit.sum(axis=0), n, confidence),
        clearance=clearance,
        radius=r,
        seed=seed,
        n=n,
        body=body,
    )


def mixture_monte_carlo(
    model,
    trajectory,
    environment: Environment,
    n: int = 100_000,
    seed: int = 0,
    *,
    confidence: float = 0.95,
) -> MixtureMonteCarlo:
    """Monte Carlo of the model's mixtures along a trajectory.

    Each trial draws one point from every configuration's mixture independently
    (:func:`~riskplan.collision.monte_carlo_trajectory`, ``combine="weighted"``) and counts a
    collision if any lies inside an obstacle: the quantity eq. 10 bounds under the paper's
    independence assumption.

    Parameters
    ----------
    model : MDNModel
        The learned kinematics.
    trajectory : array_like, (T, m)
        Model inputs along the trajectory.
    environment : Environment
        3-D obstacles in the base frame.
    n : int
        Trials.
    seed : int
        Seed of the draws.
    confidence : float
        Two-sided confidence of the Wilson intervals.

    Returns
    -------
    MixtureMonteCarlo
        ``trajectory`` (shape ``()``) and ``per_configuration`` (``(T,)``,
        :func:`~riskplan.collision.monte_carlo_probability` per configuration: what eq. 9
        bounds).
    """
    env = check_environment(environment, dim=3)
    n = check_count(n, "n", 1)
    seed = _check_seed(seed)
    m = int(getattr(model, "n_tendons", -1))
    traj = as_array(trajectory, "trajectory", min_ndim=2)
    if traj.ndim != 2 or traj.shape[1] != m or traj.shape[0] < 1:
        raise InvalidInputError(
            f"trajectory: expected shape (T, {m}) with T >= 1 for a model of {m} tendons, got {traj.shape}"
        )
    gm = as_numpy_mixture(model.predict(traj))
    s1, s2 = spawn_seeds(seed, 2)
    return MixtureMonteCarlo(
        trajectory=monte_carlo_trajectory(gm, env, n, seed=s1, confidence=confidence),
        per_configuration=monte_carlo_probability(gm, env, n, seed=s2, confidence=confidence),
    )


def validation_table(
    model,
    trajectories: dict,
    environment: Environment,
    *,
    robot=None,
    n_robot: int = 1000,
    n_mixture: int = 100_000,
    seed: int = 0,
    radius: float | None = None,
    backend: str = "local",
    workers: int | None = None,
) -> list[dict]:
    """The "does it hold on the robot?" rows: one per named trajectory.

    Every trajectory uses the same ``seed`` (common random numbers: the same starts and
    transmission draws), which sharpens the comparison between trajectories. ``bound_union``
    ignores the weights: it bounds *some* part of the body colliding, the event the robot
    Monte Carlo counts, whereas eq. 9 bounds the probability that *a random surface point*
    of the body collides.

    Parameters
    ----------
    model : MDNModel
        The learned kinematics the trajectories were planned with.
    trajectories : dict
        ``{name: (T, m) array}`` (e.g. ``"nominal"``, ``"optimised"``), tendon displacements
        (m), or ``(T, n_config)`` configurations of a robot with base rotation/retraction.
    environment : Environment
        3-D obstacles in the robot's base frame.
    robot : TendonRobot or str or path, optional
        The robot executed (default the one the model was trained for).
    n_robot : int
        Robot executions per trajectory (:func:`execute_on_robot`).
    n_mixture : int
        Mixture Monte Carlo trials per trajectory (:func:`mixture_monte_carlo`).
    seed : int
        The common seed.
    radius : float, optional
        Radius of the conservative tube (m; :func:`execute_on_robot`).
    backend, workers
        :func:`riskplan.parallel.map_tasks`; the rows do not depend on them.

    Returns
    -------
    list of dict
        Per trajectory: ``name``, ``T``, ``bound`` (eq. 10 over eq. 9, the planner's
        objective), ``bound_union`` (eq. 10 over the any-component variant of eq. 9),
        ``max_config_bound`` (largest eq.-9 term), ``mixture_mc`` / ``mixture_low`` /
        ``mixture_high``, ``robot_mc`` / ``robot_low`` / ``robot_high`` / ``robot_hits`` /
        ``robot_per_config`` (the tube), the same with prefix ``robot_disks_`` for the
        backbone-plus-disks body (``body="disks"``, the same executions; None for a
        trajectory with base retraction), ``radius`` and ``n_robot``.
    """
    if not isinstance(trajectories, dict) or not trajectories:
        raise InvalidInputError("trajectories: expected a non-empty dict {name: (T, m) array}")
    robot = _validation_robot(model, robot)
    rows = []
    for name, traj in trajectories.items():
        traj = _check_trajectory(traj, robot)
        gm = as_numpy_mixture(model.predict(traj))
        per = mixture_bound(gm, environment)
        mix = mixture_monte_carlo(model, traj, environment, n_mixture, seed)
        rob = execute_on_robot(
            robot, traj, environment, n_robot, seed, radius=radius, backend=backend, workers=workers
        )
        # the disks sit at the unretracted robot's arc lengths: a retracted robot's body is
        # another geometry, so its executions are judged with the tube only
        retracts = traj.shape[1] != robot.n_tendons and robot.base_motion.retraction
        dsk = (
            None
            if retracts
            else execute_on_robot(
                robot,
                traj,
                environment,
                n_robot,
                seed,
                body="disks",
                backend=backend,
                workers=workers,
            )
        )
        rows.append(
            {
                "name": str(name),
                "T": int(traj.shape[0]),
                "bound": float(trajectory_bound(gm, environment)),
                "bound_union": float(trajectory_bound(gm, environment, mixture_combine="union")),
                "max_config_bound": float(per.max()),
                "mixture_mc": float(mix.trajectory.probability),
                "mixture_low": float(mix.trajectory.low),
                "mixture_high": float(mix.trajectory.high),
                "n_mixture": int(n_mixture),
                **_execution_columns("robot", rob),
                **_execution_columns("robot_disks", dsk),
                "n_robot": int(n_robot),
                "radius": rob.radius,
            }
        )
    return rows


def _validation_robot(model, robot):
    """The robot executed: ``robot``, or the model's own; its inputs must match the model's."""
    from riskplan.robots import robot_from_toml

    if robot is None:
        if not getattr(model, "robot_toml", ""):
            raise InvalidInputError("robot: the model carries no robot description; pass robot=")
        robot = robot_from_toml(model.robot_toml)
    robot = _as_robot(robot)
    # a model of a robot with base motion takes its configurations (tendons, rotation,
    # retraction): its input count is the robot's n_config
    if int(model.n_tendons) not in (robot.n_tendons, robot.n_config):
        raise InvalidInputError(
            f"model: has {model.n_tendons} inputs, robot {robot.name!r} has {robot.n_tendons} "
            f"tendons ({robot.n_config} configuration variables)"
        )
    return robot


def _execution_columns(prefix: str, rob) -> dict:
    """A validation row's columns of one robot Monte Carlo (None where it was not run)."""
    keys = ("mc", "low", "high", "hits", "per_config")
    if rob is None:
        return {f"{prefix}_{k}": None for k in keys}
    t = rob.trajectory
    values = (float(t.probability), float(t.low), float(t.high), int(t.hits))
    values += (rob.per_configuration.probability.tolist(),)
    return {f"{prefix}_{k}": v for k, v in zip(keys, values)}
