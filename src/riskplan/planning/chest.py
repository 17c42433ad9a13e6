"""Chest-cavity planning pipeline (MDN paper section V, Figs. 6-7): roadmap, nominal
trajectory, Bayesian optimisation of its eq.-10 bound, optional least-risk roadmap path.

Frames: the learned model predicts mixtures in the robot *base* frame, so every environment
passed here is in the base frame (:attr:`riskplan.planning.chest_scene.Chest.base_environment`, or
a user mesh mapped with :func:`riskplan.collision.load_environment`). Goal tips are base-frame points.

Default scene. Start: zero displacement (the straight robot, free in the procedural chest).
Goal: :data:`DEFAULT_GOAL`, chosen on the robot model itself by :func:`recess_goal`
(the rule: among the configurations whose simulated tip lies in the posterior costophrenic
recess -- caudal and posterior of the port, within :data:`RECESS_DEPTH` of the diaphragm, where
a pleural effusion pools -- the one whose body, backbone and disks as the cameras saw them,
keeps the largest clearance from every obstacle). :data:`DEFAULT_GOAL_TIP` is that
configuration's simulated tip. docs/validation.md records the search and the executions that
show start and goal free on the robot; the eq.-10 bound is whatever eq. 10 says there.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from riskplan.errors import InvalidInputError
from riskplan.kinematics_model import KinematicsModel, _checked_limits
from riskplan.planning.bo import OptimiserConfig
from riskplan.planning.prm import (
    DEFAULT_MILESTONES,
    DEFAULT_RESOLUTION,
    DEFAULT_STEP,
    DEFAULT_TIP_TOLERANCE,
)
from riskplan.planning.risk import RISKS
from riskplan.planning.robot_plan import RobotPlan, plan_robot

log = logging.getLogger(__name__)

# The tip must sit in the fluid that pools on the diaphragm: an effusion worth draining is a
# layer of a few centimetres at the base (docs/validation.md: sensitivity to this depth)
RECESS_DEPTH = 0.02
#: the obstacle whose neighbourhood is the recess floor
RECESS_FLOOR = "diaphragm"
#: :func:`recess_goal` for the ``paper`` robot in ``build_chest(0)`` (seed 0), rounded to 0.01 mm;
#: tendon displacements [m]
DEFAULT_GOAL = (-0.00886, 0.0011, 0.00463, 0.0094)
#: the simulated tip of :data:`DEFAULT_GOAL`, base frame (x cranial, y anterior, z medial) [m]
DEFAULT_GOAL_TIP = (-0.02595, -0.01539, 0.19667)


#: what :func:`plan_chest` returns: the scene-agnostic planner's result
ChestPlan = RobotPlan


def plan_chest(
    model: KinematicsModel,
    environment,
    *,
    start=None,
    goal=None,
    goal_tip=None,
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
) -> ChestPlan:
    r"""Plan a nominal trajectory with a PRM and lower its eq.-10 bound (MDN paper section V).

    The chest's use of :func:`riskplan.planning.robot_plan.plan_robot` (the paper robot has no
    base motion: planning coordinates are the displacements). Per configuration the risk
    ``p_t`` (eq. 9 by default); along the trajectory eq. 10:

    .. math:: P(\text{collision}) \le 1 - \prod_t (1 - p_t)

    Parameters
    ----------
    model : KinematicsModel
        The robot's kinematics model: the learned :class:`~riskplan.kinematics.MDNModel`
        (inputs ``(m,)`` tendon displacements, m) or any object with the members of
        :class:`~riskplan.kinematics_model.KinematicsModel` (docs/planning.md, "Your own
        model"); :class:`InvalidInputError` if it lacks them.
    environment : Environment
        3-D obstacles in the robot base frame (m).
    start, goal : array_like, (m,), optional
        Displacements; start default: zeros clipped to the limits. When neither ``goal`` nor
        ``goal_tip`` is given, :data:`DEFAULT_GOAL` (the :func:`recess_goal` rule, for the
        ``paper`` robot in ``build_chest(0)``; other models with 4 tendons get it too, others
        need a goal).
    goal_tip : array_like, (3,), optional
        A base-frame tip target: the valid configuration whose predicted tip is closest
        (:func:`~riskplan.planning.prm.goal_from_tip`), within ``tip_tolerance``.
    tip_tolerance : float
        Largest accepted distance of the predicted tip from ``goal_tip`` (m).
    n_milestones : int
        PRM milestones (:func:`build_roadmap`).
    step, resolution : float
        Trajectory step and motion-check spacing (m of displacement).
    optimiser : OptimiserConfig, optional
        Settings of :func:`optimise_trajectory`.
    seed : int
        Seed of the roadmap and the optimiser.
    least_risk : bool
        Also search the roadmap for the least-risk path (edge cost ``-log(1 - p)``) and report
        both paths' bounds.
    risk : str
        The per-configuration risk optimised: ``"eq9"`` (the paper's bound, the default),
        ``"cloud"`` (:class:`~riskplan.planning.risk.CloudRiskBound`, body contact) or
        ``"bodies"`` (:class:`~riskplan.planning.risk.SampledBodyRisk`, body contact over
        sampled executions).
    checkpoint : str or path, optional
        JSON file of the optimiser's state, written atomically after every iteration.
    resume : bool
        Continue from ``checkpoint``.
    roadmap_progress, optimise_progress, risk_progress : callable, optional
        Progress callbacks of the three stages.

    Returns
    -------
    ChestPlan
        The nominal and optimised trajectories ``(T, m)`` with their bounds.
    """
    if risk not in RISKS:  # before the goal: a bad option is named first
        raise InvalidInputError(f"risk: expected one of {RISKS}, got {risk!r}")
    # the members and limits now (the default goal needs m), the prediction in plan_robot's
    # full check: one probe per call
    limits = _checked_limits(model)
    if goal is None and goal_tip is None:
        m = len(limits)
        if m != len(DEFAULT_GOAL):
            raise InvalidInputError(
                f"goal: the default goal has {len(DEFAULT_GOAL)} tendons, the model {m}; "
                "give goal or goal_tip"
            )
        goal = np.asarray(DEFAULT_GOAL, dtype=np.float64)
    return plan_robot(
        model,
        environment,
        start=start,
        goal=goal,
        goal_tip=goal_tip,
        tip_tolerance=tip_tolerance,
        n_milestones=n_milestones,
        step=step,
        resolution=resolution,
        optimiser=optimiser,
        seed=seed,
        least_risk=least_risk,
        risk=risk,
        checkpoint=checkpoint,
        resume=resume,
        roadmap_progress=roadmap_progress,
        optimise_progress=optimise_progress,
        risk_progress=risk_progress,
    )


def _finite_positive(v, name):
    if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
        raise InvalidInputError(f"{name}: expected a finite number > 0, got {v!r}")
    return float(v)


@dataclass(frozen=True)
class RecessGoal:
    """Result of :func:`recess_goal`.

    Attributes
    ----------
    goal: ``(m,)`` tendon displacements [m].
    tip: ``(3,)`` simulated tip, base frame [m].
    clearance: smallest signed distance of the body (backbone tube + disks) to any obstacle [m].
    floor_distance: distance of the tip to the recess floor obstacle [m].
    evaluated: configurations solved; ``in_recess``: how many of the random draws had their
        tip in the recess (and within the tension limits).
    """

    goal: np.ndarray
    tip: np.ndarray
    clearance: float
    floor_distance: float
    evaluated: int
    in_recess: int


def body_clearance(robot, configurations, environment) -> tuple[np.ndarray, np.ndarray]:
    """Tip ``(N, 3)`` and body clearance ``(N,)`` [m] of ``robot`` at ``configurations (N, m)``
    without transmission variation (the nominal Cosserat shape, base frame).

    The body is the one the cameras saw and the MDN learned: the backbone tube of the backbone
    radius plus the separator disks (:func:`~riskplan.planning.clearance.disk_clearance`), the
    ``body="disks"`` test of :func:`~riskplan.planning.validate.execute_on_robot`.
    Inputs are trusted.
    """
    from riskplan.datasets.generate import to_base_frame
    from riskplan.planning.clearance import disk_clearance, tube_clearance
    from riskplan.robots.geometry import BodyGeometry

    geom = BodyGeometry.from_params(robot.params)
    shape = robot.solve_displacements(np.asarray(configurations, dtype=np.float64), validate=False)
    P, R = to_base_frame(robot, shape.positions, shape.rotations)
    c = np.minimum(
        tube_clearance(environment, P, geom.backbone_radius),
        disk_clearance(environment, robot.s, P, R, geom),
    )
    return P[:, -1], c


def recess_goal(
    robot,
    environment,
    *,
    floor: str = RECESS_FLOOR,
    depth: float = RECESS_DEPTH,
    n_samples: int = 4096,
    refine: int = 128,
    seed: int = 0,
) -> RecessGoal:
    r"""The default goal rule: reach the recess, with the most room.

    Clinical intent: the tip in the posterior costophrenic recess, where a pleural effusion
    pools -- caudal (base ``x < 0``) and posterior (base ``y < 0``) of the port and within
    ``depth`` of the ``floor`` obstacle (the diaphragm) -- reached with clearance. Among the
    configurations within the displacement and tension limits whose simulated tip lies there,
    the one maximising the body's smallest clearance to every obstacle (:func:`body_clearance`):

    .. math:: d^* = \arg\max_{d:\ \mathrm{tip}(d) \in \mathcal{R}} \min_{x \in \mathrm{body}(d)} \mathrm{sd}(x)

    Search on the robot model itself (no learned model): ``n_samples`` seeded uniform draws,
    then four rounds of ``refine`` Gaussian perturbations (4, 2, 1, 0.5 mm) around the best.
    :class:`~riskplan.errors.PlanningError` if no draw reaches the recess.

    Parameters
    ----------
    robot : TendonRobot
        The simulated robot.
    environment : Environment
        3-D obstacles in its base frame, one of them named ``floor``.
    floor : str
        Name of the recess floor obstacle.
    depth : float
        Largest distance of the tip from the floor (m).
    n_samples : int
        Uniform draws in the displacement box.
    refine : int
        Perturbations per refinement round.
    seed : int
        Seed of the draws.

    Returns
    -------
    RecessGoal
        The goal ``(m,)``, its tip ``(3,)``, the body's clearance and the tip's floor distance (m).
    """
    from riskplan.errors import PlanningError

    env = environment
    if floor not in env.names:
        raise InvalidInputError(f"floor: no obstacle named {floor!r} in {env.names}")
    depth = _finite_positive(depth, "depth")
    floor_env = env.subset([floor])
    lim = np.asarray(robot.displacement_limits, dtype=np.float64)
    rng = np.random.default_rng(seed)

    def score(q):
        ok = (robot.tensions_for_displacements(q, validate=False) <= robot.tension_limits).all(-1)
        q = q[ok]
        tip, c = body_clearance(robot, q, env) if len(q) else (np.empty((0, 3)), np.empty(0))
        df = floor_env.signed_distance(tip)
        inside = (tip[:, 0] < 0) & (tip[:, 1] < 0) & (df > 0) & (df <= depth)
        return q[inside], tip[inside], c[inside], df[inside]

    q0 = lim[:, 0] + rng.random((int(n_samples), len(lim))) * (lim[:, 1] - lim[:, 0])
    q, tip, c, df = score(q0)
    evaluated, in_recess = len(q0), len(q)
    if not len(q):
        raise PlanningError(
            f"no configuration of {n_samples} draws puts the tip within {depth * 1e3:.0f} mm of "
            f"{floor!r}, caudal and posterior of the port"
        )
    b = int(np.argmax(c))
    best = (q[b], tip[b], float(c[b]), float(df[b]))
    for scale in (4e-3, 2e-3, 1e-3, 5e-4):
        loc = np.clip(best[0] + scale * rng.standard_normal((int(refine), len(lim))), *lim.T)
        evaluated += len(loc)
        q, tip, c, df = score(loc)
        if len(q) and c.max() > best[2]:
            b = int(np.argmax(c))
            best = (q[b], tip[b], float(c[b]), float(df[b]))
    return RecessGoal(best[0], best[1], best[2], best[3], evaluated, in_recess)
