"""Planning a tendon robot under kinematic uncertainty (MDN paper section V, Figs. 6-7): the
kinematic wing's top. Tissue planning is :mod:`riskplan.tissue_planning`.

* :mod:`riskplan.planning.prm` — OMPL PRM in tendon-displacement space with the paper's
  validity condition (component means in free space, :mod:`riskplan.planning.roadmap`),
  nominal trajectories;
* :mod:`riskplan.planning.risk` — eq. 9/10 along plans, least-risk roadmap search;
* :mod:`riskplan.planning.bo` — the paper's Bayesian optimisation of the nominal trajectory
  and the comparison optimisers;
* :mod:`riskplan.planning.chest` — the whole pipeline on a model and a mesh;
* :mod:`riskplan.planning.validate` — does a planned trajectory hold on the simulated robot?
* :mod:`riskplan.planning.chest_scene` — the procedural chest cavity the paper plans in.
"""

from riskplan.planning.bo import OptimisationResult, OptimiserConfig, optimise_trajectory
from riskplan.planning.chest import ChestPlan, RecessGoal, plan_chest, recess_goal
from riskplan.planning.chest_scene import Chest, ChestParams, build_chest
from riskplan.planning.clearance import tube_clearance
from riskplan.planning.prm import (
    MeanValidity,
    Roadmap,
    build_roadmap,
    goal_from_tip,
    interpolate_path,
    tip_positions,
)
from riskplan.planning.problem import Problem, load_problem
from riskplan.planning.risk import (
    ConfigurationBound,
    compare_paths,
    least_risk_path,
    trajectory_risk,
)
from riskplan.planning.robot_plan import RobotPlan, plan_robot
from riskplan.planning.validate import (
    MixtureMonteCarlo,
    RobotMonteCarlo,
    execute_on_robot,
    mixture_monte_carlo,
    validation_table,
)

__all__ = [
    "Chest",
    "ChestParams",
    "ChestPlan",
    "ConfigurationBound",
    "MeanValidity",
    "MixtureMonteCarlo",
    "OptimisationResult",
    "OptimiserConfig",
    "Problem",
    "RecessGoal",
    "Roadmap",
    "RobotMonteCarlo",
    "RobotPlan",
    "build_chest",
    "build_roadmap",
    "compare_paths",
    "execute_on_robot",
    "goal_from_tip",
    "interpolate_path",
    "least_risk_path",
    "load_problem",
    "mixture_monte_carlo",
    "optimise_trajectory",
    "plan_chest",
    "plan_robot",
    "recess_goal",
    "tip_positions",
    "trajectory_risk",
    "tube_clearance",
    "validation_table",
]
