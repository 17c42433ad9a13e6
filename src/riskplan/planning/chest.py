"""Chest-cavity planning pipeline (MDN paper section V, Figs. 6-7): roadmap, nominal
trajectory, Bayesian optimisation of its eq.-10 bound, optional least-risk roadmap path.

Frames: the learned model predicts mixtures in the robot *base* frame, so every environment
passed here is in the base frame (:attr:`riskplan.scenarios.chest.Chest.base_environment`, or
a user mesh mapped with :func:`riskplan.collision.load_environment`). Goal tips are base-frame points.

Default scene (issue part 3): start at zero displacement (the straight robot, free in the
procedural chest) and a goal tip in the effusion pocket, :data:`DEFAULT_GOAL_TIP`: 5 cm
caudal, 6 cm posterior and 17 cm medial of the port (base frame), i.e. in the posterior,
dependent part of the pocket just above the diaphragm dome, where a pleural effusion pools
(the posterior costophrenic recess). docs/planning.md lists the scan of pocket targets behind
this choice and the bound it gives; the bound is whatever eq. 10 says.
"""

from __future__ import annotations

import logging

from riskplan.planning.bo import OptimiserConfig
from riskplan.planning.prm import (
    DEFAULT_MILESTONES,
    DEFAULT_RESOLUTION,
    DEFAULT_STEP,
    DEFAULT_TIP_TOLERANCE,
)
from riskplan.planning.robot_plan import RobotPlan, plan_robot

log = logging.getLogger(__name__)

# base frame: x cranial, y anterior (z cross x), z medial (insertion direction); metres
DEFAULT_GOAL_TIP = (-0.05, -0.06, 0.17)


#: what :func:`plan_chest` returns: the scene-agnostic planner's result
ChestPlan = RobotPlan


def plan_chest(
    model,
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
    checkpoint=None,
    resume: bool = False,
    roadmap_progress=None,
    optimise_progress=None,
    risk_progress=None,
) -> ChestPlan:
    """Plan a nominal trajectory with a PRM and lower its eq.-10 bound (paper section V).

    ``model``: an :class:`~riskplan.kinematics.MDNModel`; ``environment``: base-frame
    :class:`~riskplan.collision.Environment`; ``start``/``goal`` ``(m,)`` displacements (start
    default: zeros clipped to the limits), or ``goal_tip (3,)`` base frame (default
    :data:`DEFAULT_GOAL_TIP` when neither is given). ``least_risk``: also search the roadmap
    for the least-risk path (edge cost ``-log(1 - p)``) and report both paths' bounds.
    The chest's use of :func:`riskplan.planning.robot_plan.plan_robot` (the paper robot has
    no base motion: planning coordinates are the displacements).
    """
    if goal is None and goal_tip is None:
        goal_tip = DEFAULT_GOAL_TIP
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
        checkpoint=checkpoint,
        resume=resume,
        roadmap_progress=roadmap_progress,
        optimise_progress=optimise_progress,
        risk_progress=risk_progress,
    )
