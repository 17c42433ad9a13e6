"""The MDN paper's planner (section V) for any robot in any scene: roadmap, nominal trajectory,
Bayesian optimisation of its eq.-10 bound.

:func:`plan_robot` is the scene-agnostic pipeline; :func:`riskplan.planning.chest.plan_chest`
is the chest cavity's use of it (its default goal tip and outputs).

Configuration space
-------------------
The learned model's inputs: tendon displacements (m), then base rotation (rad) and retraction
(m) where the robot has them (:meth:`riskplan.robots.TendonRobot.split_configuration`). The
roadmap, the motion checks (``resolution``), the trajectory step (``step``) and the optimiser's
neighbourhoods measure distances in *planning coordinates* ``y = w * x``, one weight per
input (:func:`configuration_weights`): 1 for a tendon displacement and for retraction (a
retraction of 1 mm moves the tip by 1 mm), the robot's length ``L`` (m/rad) for rotation (a
rotation by ``theta`` moves a point of the robot at most ``L theta``, its largest distance
from the axis). So the 1 mm motion resolution bounds how far the base motions move the robot
between checked configurations, as it bounds a tendon's travel; without the weight a full-turn
rotation (6.3 rad) would count as 6.3 m of motion. A robot without base motion has all weights
1 and plans exactly as before. Rotation is planned within its limits as an interval (a motion
does not wrap through ``+-pi``).

The box searched is the box the model was trained on (``box``: the data-set protocol's
limits, :attr:`riskplan.datasets.protocol.Protocol.limits`) when given, else the model's
limits: outside the training data the MDN extrapolates.

Scenes
------
``environment``: an :class:`~riskplan.collision.Environment` of closed obstacles in the robot
base frame (the paper's condition: every component mean outside every obstacle), or a
:class:`~riskplan.planning.problem_scene.WallEnvironment`: surfaces that need not be closed
(an anatomy surface with an opening for the robot, as in the Kuntz lab's task files), obstacles
to be crossed rather than entered. There a motion is valid when, in addition, no component mean
crosses a surface between two checked configurations; eq. 9 is the same Patil construction
against the nearest surfaces. :func:`~riskplan.planning.problem_scene.problem_environment`
builds the scene of a :class:`~riskplan.planning.problem.Problem`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from riskplan._validation import as_array
from riskplan.errors import InvalidInputError
from riskplan.kinematics_model import KinematicsModel, check_kinematics_model
from riskplan.planning.bo import OptimisationResult, OptimiserConfig, optimise_trajectory
from riskplan.planning.prm import (
    DEFAULT_MILESTONES,
    DEFAULT_RESOLUTION,
    DEFAULT_STEP,
    DEFAULT_TIP_TOLERANCE,
    MeanValidity,
    Roadmap,
    build_roadmap,
    goal_from_tip,
    interpolate_path,
)
from riskplan.planning.risk import RISKS, compare_paths, make_risk, trajectory_risk

log = logging.getLogger(__name__)

__all__ = [
    "RobotPlan",
    "ScaledModel",
    "check_plan_budget",
    "configuration_weights",
    "plan_robot",
]


@dataclass
class RobotPlan:
    """Everything :func:`plan_robot` computed. Configurations are model inputs ``(T, n)``
    (tendon displacements [m], then rotation [rad] and retraction [m] where enabled); the
    roadmap is in planning coordinates (``weights * x``)."""

    roadmap: Roadmap
    start: np.ndarray
    goal: np.ndarray
    goal_tip: np.ndarray | None
    path: np.ndarray
    nominal: np.ndarray
    nominal_bounds: np.ndarray
    nominal_bound: float
    optimised: OptimisationResult
    paths: dict | None = None
    timings: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    weights: np.ndarray | None = None


class ScaledModel:
    """The model seen in planning coordinates ``y = weights * x``: ``predict(y)`` is
    ``model.predict(y / weights)``, ``limits`` the box scaled by ``weights``."""

    def __init__(self, model, weights, box=None):
        self.model = model
        self.weights = np.asarray(weights, dtype=np.float64)
        box = np.asarray(model.limits if box is None else box, dtype=np.float64)
        self.box = box
        self.limits = box * self.weights[:, None]
        # optional members of a kinematics model (riskplan.kinematics_model)
        self.n_tendons = getattr(model, "n_tendons", box.shape[0])
        self.robot = getattr(model, "robot", None)

    def to_model(self, y) -> np.ndarray:
        """Model inputs ``x = y / weights``.

        Parameters
        ----------
        y : array_like, shape (..., n_inputs)
            Planning coordinates.

        Returns
        -------
        numpy.ndarray
            Model inputs, same shape.
        """
        return np.asarray(y, dtype=np.float64) / self.weights

    def to_planning(self, x) -> np.ndarray:
        """Planning coordinates ``y = weights * x``.

        Parameters
        ----------
        x : array_like, shape (..., n_inputs)
            Model inputs.

        Returns
        -------
        numpy.ndarray
            Planning coordinates, same shape.
        """
        return np.asarray(x, dtype=np.float64) * self.weights

    def predict(self, y, *args, **kwargs):
        """The model's prediction at planning coordinates ``y``, clipped into the box.

        Parameters
        ----------
        y : array_like, shape (..., n_inputs)
            Planning coordinates.
        *args, **kwargs
            Handed to ``model.predict``.

        Returns
        -------
        GaussianMixture
            What ``model.predict`` returns.
        """
        # exact at the box's faces: y / w * w may differ from x by an ulp
        x = np.clip(self.to_model(y), self.box[:, 0], self.box[:, 1])
        return self.model.predict(x, *args, **kwargs)


def configuration_weights(robot, n_inputs: int) -> np.ndarray:
    """``(n_inputs,)`` planning weights (module docs): 1 per tendon and for retraction, the
    robot's length (m/rad) for rotation. All ones for a robot without base motion or
    ``robot=None``.

    Parameters
    ----------
    robot : TendonRobot or None
        The robot.
    n_inputs : int
        The model's inputs.

    Returns
    -------
    numpy.ndarray
        ``(n_inputs,)`` weights.
    """
    w = np.ones(int(n_inputs))
    if robot is None:
        return w
    bm = getattr(robot, "base_motion", None)
    if bm is not None and bm.rotation and n_inputs > robot.n_tendons:
        w[robot.n_tendons] = float(robot.params.backbone.length)
    return w


def _finite_positive(v, name):
    if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
        raise InvalidInputError(f"{name}: expected a finite number > 0, got {v!r}")
    return float(v)


#: least memory of one roadmap milestone (bytes): its coordinates, about k = 10 edges read back
#: from OMPL (two int64 each, shared by two milestones), the search's adjacency lists and its
#: distance, predecessor and settled arrays; OMPL's own copy of the graph comes on top
MILESTONE_BYTES = 250.0
#: least time of one configuration of one robot execution in the validation (s): a tenth of
#: the measured 0.39 ms of a Cosserat solve (docs/reproduce.md, 2-core AMD EPYC, shared)
ROBOT_CONFIG_S = 0.039e-3


def check_plan_budget(
    limits,
    *,
    n_milestones: int,
    step: float,
    resolution: float,
    optimiser: OptimiserConfig,
    executions: int = 0,
) -> None:
    """Refuse a plan whose work exceeds the budget (:mod:`riskplan.budget`), before any
    work, naming the option: the roadmap (``--milestones``; its motion checks at
    ``--resolution``, a motion about the typical neighbour distance ``diag / n^(1/m)`` long),
    the trajectory (``--step``; estimated for a path across the displacement box's diagonal),
    the optimiser (``bo_checks.check_optimiser_budget``) and the validation
    (``--executions`` of the nominal and the optimised trajectory on the robot).

    Parameters
    ----------
    limits : array_like, shape (n_config, 2)
        The configuration box.
    n_milestones : int
        Roadmap milestones.
    step : float
        Trajectory step.
    resolution : float
        Motion-check resolution.
    optimiser : OptimiserConfig
        The optimiser's settings.
    executions : int
        Validation executions.
    """
    from riskplan.budget import check_budget
    from riskplan.planning.bo_checks import MOTION_STATE_BYTES, check_optimiser_budget

    lim = np.asarray(limits, dtype=np.float64)
    m = lim.shape[0]
    diag = float(np.linalg.norm(lim[:, 1] - lim[:, 0]))
    n = float(n_milestones)
    check_budget(
        f"a roadmap of {n_milestones} milestones", "--milestones", nbytes=n * MILESTONE_BYTES
    )
    neighbour = diag / max(n, 1.0) ** (1.0 / m)
    states = neighbour / resolution + 1
    check_budget(
        f"motion checks at resolution {resolution:g} ({states:.3g} states per motion)",
        "--resolution",
        nbytes=states * MOTION_STATE_BYTES * m,
    )
    T = diag / step + 2
    check_budget(
        f"a trajectory of about {T:.3g} configurations at step {step:g}",
        "--step",
        nbytes=T * 8.0 * m * 4,  # the trajectory, its bounds, the optimiser's copies
    )
    check_optimiser_budget(optimiser, int(min(T, 2**62)), lim)
    if executions:
        check_budget(
            f"{executions} robot executions of 2 trajectories of about {T:.3g} configurations",
            "--executions",
            seconds=2.0 * float(executions) * T * ROBOT_CONFIG_S,
        )


def plan_robot(
    model: KinematicsModel,
    environment,
    *,
    start=None,
    goal=None,
    goal_tip=None,
    box=None,
    weights=None,
    tip_tolerance: float = DEFAULT_TIP_TOLERANCE,
    n_milestones: int = DEFAULT_MILESTONES,
    step: float = DEFAULT_STEP,
    resolution: float = DEFAULT_RESOLUTION,
    optimiser: OptimiserConfig | None = None,
    seed: int = 0,
    least_risk: bool = False,
    risk: str = "eq9",
    checkpoint=None,
    resume: bool = False,
    roadmap_progress=None,
    optimise_progress=None,
    risk_progress=None,
) -> RobotPlan:
    r"""Plan a nominal trajectory with a PRM and lower its eq.-10 bound (MDN paper section V).

    A roadmap over the valid configurations, the shortest path from start to goal (and, asked
    for, the least-risk one), the nominal trajectory at ``step``, and the optimisation of its
    bound (:func:`~riskplan.planning.optimise_trajectory`). Eq. 9 bounds each configuration's
    collision probability :math:`p_t`, eq. 10 the trajectory's,
    :math:`P = 1 - \prod_t (1 - p_t)`. Raises :class:`InvalidInputError` for malformed or
    invalid inputs before any work, :class:`~riskplan.errors.PlanningError` when no path or
    goal is found.

    Parameters
    ----------
    model : KinematicsModel
        The robot's kinematics model (inputs ``(n,)``, see the module docs): the learned
        :class:`~riskplan.kinematics.MDNModel` or any object with the members of
        :class:`~riskplan.kinematics_model.KinematicsModel` (:class:`InvalidInputError` if it
        lacks them).
    environment : Environment or WallEnvironment
        Obstacles in the robot base frame (m).
    start, goal : array_like, shape (n,), optional
        Model inputs; start default zeros clipped to the box. Give exactly one of ``goal``
        and ``goal_tip`` (a ``(3,)`` base-frame tip target, m, reached within
        ``tip_tolerance`` m).
    goal_tip, tip_tolerance
        See ``goal``.
    box : array_like, shape (n, 2), optional
        The box to search (default the model's limits), within the model's limits.
    weights : array_like, shape (n,), optional
        Planning weights (default :func:`configuration_weights` of the model's robot).
    n_milestones, seed : int
        Roadmap milestones; seed of the roadmap, the goal search and the optimiser.
    step, resolution : float
        Trajectory step and motion-check spacing, planning coordinates.
    optimiser : OptimiserConfig, optional
        The optimiser's settings; ``checkpoint`` (a JSON file) and ``resume`` are its own.
    checkpoint, resume
        See ``optimiser``.
    least_risk : bool
        Also search the roadmap for the least-risk path (edge cost ``-log(1 - p)``).
    risk : {"eq9", "cloud", "bodies"}
        The per-configuration risk optimised: the paper's bound, or body contact
        (:class:`~riskplan.planning.risk.CloudRiskBound`,
        :class:`~riskplan.planning.risk.SampledBodyRisk`).
    roadmap_progress, optimise_progress, risk_progress : callable, optional
        Progress callbacks of the three stages.

    Returns
    -------
    RobotPlan
        Roadmap, path and nominal trajectory ``(T, n)`` (model inputs) with their bounds, the
        optimisation result, timings (s), settings.
    """
    optimiser, box, weights = _check_plan_arguments(
        model, box, weights, goal, goal_tip, risk, step, resolution, tip_tolerance, optimiser,
        n_milestones,
    )  # fmt: skip
    scaled = ScaledModel(model, weights, box)
    start, goal, validity = _check_ends(scaled, environment, start, goal)
    timings = {}
    t = time.perf_counter()
    roadmap = build_roadmap(
        validity, n_milestones=n_milestones, seed=seed, resolution=resolution,
        progress=roadmap_progress,
    )  # fmt: skip
    timings["roadmap_s"] = time.perf_counter() - t
    ys = scaled.to_planning(start)
    if goal is None:
        goal_tip = as_array(goal_tip, "goal_tip", shape=(3,))
        yg = goal_from_tip(roadmap, scaled, goal_tip, tolerance=tip_tolerance, seed=seed)
        goal = scaled.to_model(yg)
    else:
        yg = scaled.to_planning(goal)
    bound = make_risk(risk, scaled, environment)
    t = time.perf_counter()
    paths, path, nominal, nominal_bound, nominal_bounds = _nominal(
        roadmap, bound, scaled, ys, yg, step, least_risk, risk_progress
    )
    timings["query_s"] = time.perf_counter() - t
    t = time.perf_counter()
    res = _optimise(
        nominal, nominal_bounds, bound, validity, optimiser, seed, checkpoint, resume,
        optimise_progress,
    )  # fmt: skip
    timings["optimise_s"] = time.perf_counter() - t
    res = dataclasses.replace(res, trajectory=scaled.to_model(res.trajectory))
    settings = _plan_settings(
        roadmap, optimiser, n_milestones, step, resolution, seed, tip_tolerance, risk, weights, box
    )
    tip = None if goal_tip is None else np.asarray(goal_tip, dtype=np.float64)
    return RobotPlan(
        roadmap, start, goal, tip, scaled.to_model(path), scaled.to_model(nominal),
        nominal_bounds, nominal_bound, res, paths, timings, settings, weights,
    )  # fmt: skip


def _nominal(roadmap, bound, scaled, ys, yg, step, least_risk, progress):
    """The shortest path from ``ys`` to ``yg`` (with the least-risk comparison, asked for, in
    model inputs) and the nominal trajectory at ``step`` with its bounds (eq. 10, eq. 9 per
    configuration); planning coordinates."""
    paths = None
    if least_risk:
        paths = compare_paths(roadmap, bound, ys, yg, step=step, progress=progress)
        path = paths["shortest"]["path"]
    else:
        path = roadmap.shortest_path(ys, yg)
    nominal = interpolate_path(path, step)
    nominal_bound, nominal_bounds = trajectory_risk(bound, nominal)
    for v in (paths or {}).values():
        v["path"] = scaled.to_model(v["path"])
        v["trajectory"] = scaled.to_model(v["trajectory"])
    return paths, path, nominal, nominal_bound, nominal_bounds


def _optimise(
    nominal, nominal_bounds, bound, validity, optimiser, seed, checkpoint, resume, progress
) -> OptimisationResult:
    """The nominal trajectory's bound lowered (:func:`optimise_trajectory`), planning
    coordinates."""
    # a configuration's eq.-9 bound may be exactly 1 (a mean touching a surface): the optimiser's
    # log1p(-p) is then -inf, exactly what eq. 10 needs, not an error
    with np.errstate(divide="ignore"):
        return optimise_trajectory(
            nominal,
            bound,
            validity,
            validity.limits,
            config=optimiser,
            seed=seed,
            bounds=nominal_bounds,
            checkpoint=checkpoint,
            resume=resume,
            progress=progress,
        )


def _check_plan_arguments(
    model, box, weights, goal, goal_tip, risk, step, resolution, tip_tolerance, optimiser,
    n_milestones,
):  # fmt: skip
    """``plan_robot``'s settings checked before any work, its budget included: (optimiser,
    box ``(n, 2)`` within the model's limits, weights ``(n,)`` > 0)."""
    optimiser = optimiser or OptimiserConfig()
    optimiser.validate()
    if risk not in RISKS:
        raise InvalidInputError(f"risk: expected one of {RISKS}, got {risk!r}")
    full = check_kinematics_model(model)
    for name, v in (("step", step), ("resolution", resolution), ("tip_tolerance", tip_tolerance)):
        _finite_positive(v, name)
    if goal is not None and goal_tip is not None:
        raise InvalidInputError(
            "give either goal (displacements) or goal_tip (a tip target), not both"
        )
    if goal is None and goal_tip is None:
        raise InvalidInputError("give a goal (configuration) or a goal_tip (tip target)")
    n = full.shape[0]
    box = full if box is None else as_array(box, "box", shape=(n, 2))
    if (
        np.any(box[:, 0] > box[:, 1])
        or np.any(box[:, 0] < full[:, 0] - 1e-12)
        or np.any(box[:, 1] > full[:, 1] + 1e-12)
    ):
        raise InvalidInputError(
            f"box: {box.tolist()} must be ordered and within the model's limits {full.tolist()}"
        )
    box = np.clip(box, full[:, :1], full[:, 1:])
    if weights is None:
        weights = configuration_weights(getattr(model, "robot", None), n)
    weights = as_array(weights, "weights", shape=(n,))
    if np.any(weights <= 0):
        raise InvalidInputError(f"weights: expected > 0, got {weights.tolist()}")
    check_plan_budget(
        box * weights[:, None],
        n_milestones=n_milestones,
        step=step,
        resolution=resolution,
        optimiser=optimiser,
    )
    return optimiser, box, weights


def _check_ends(scaled: ScaledModel, environment, start, goal):
    """Start (default: zeros clipped to the box) and goal ``(n,)`` (None when a tip target
    is given), inside the box and valid, and the validity check."""
    box = scaled.box
    n = box.shape[0]
    if start is None:
        start = np.clip(np.zeros(n), box[:, 0], box[:, 1])
    start = as_array(start, "start", shape=(n,))
    if goal is not None:
        goal = as_array(goal, "goal", shape=(n,))
    validity = MeanValidity(scaled, environment)
    for name, c in (("start", start), ("goal", goal)):
        if c is None:
            continue
        if not np.all((c >= box[:, 0]) & (c <= box[:, 1])):
            raise InvalidInputError(
                f"{name}: {c.tolist()} is outside the displacement limits {box.tolist()}"
            )
        if not validity(scaled.to_planning(c)[None])[0]:
            raise InvalidInputError(
                f"{name}: configuration {c.tolist()} is invalid (a component mean of its predicted mixture lies inside an obstacle)"
            )
    return start, goal, validity


def _plan_settings(
    roadmap, optimiser, n_milestones, step, resolution, seed, tip_tolerance, risk, weights, box
) -> dict:
    """The settings a plan records (those that decide its result)."""
    settings = {
        "n_milestones": int(n_milestones),
        "step": step,
        "resolution": resolution,
        "seed": int(seed),
        "tip_tolerance": tip_tolerance,
        "risk": risk,
        "neighbours": roadmap.n_neighbours,
        "optimiser": {
            k: getattr(optimiser, k)
            for k in ("iterations", "n_candidates", "radius", "method", "resolution")
        },
    }
    if np.any(weights != 1.0):
        settings["weights"] = weights.tolist()
        settings["box"] = box.tolist()
    return settings
