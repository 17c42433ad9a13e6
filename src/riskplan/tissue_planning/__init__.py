"""Planning in deformable tissue (Patil, van den Berg & Alterovitz, RSS 2011): the simulator
RRT (:mod:`~riskplan.tissue_planning.rrt`), LQG-MP plan selection
(:mod:`~riskplan.tissue_planning.select`), its estimates against closed-loop executions
(:mod:`~riskplan.tissue_planning.calibration`) and the method end to end
(:func:`~riskplan.tissue_planning.plan.plan_tissue`); the 3-D needle's planning
(:func:`~riskplan.tissue_planning.needle3d.plan_needle3d`: candidates, LQG-MP estimators in 3-D,
the check against executions, :mod:`~riskplan.tissue_planning.needle3d_checks`).

The tissue wing's top: it imports ``scenarios`` and ``control`` and never the kinematic wing.
"""

from riskplan.tissue_planning.calibration import (
    SATURATED,
    Calibration,
    CalibrationRow,
    calibration_check,
    calibration_metrics,
    evenly_spaced_ranks,
)
from riskplan.tissue_planning.needle3d import (
    ESTIMATORS,
    GOAL_SE,
    MAX_GOAL_SAMPLES,
    MAX_PARTICLES,
    PARTICLES_BATCH,
    PARTICLES_SE,
    Needle3DResult,
    PlanRow,
    evaluate_candidates,
    measure_plan,
    plan_needle3d,
)
from riskplan.tissue_planning.needle3d_checks import (
    CHECK_POINTS,
    DRAWS_PER_TASK,
    accuracy_checks,
    execute_draws,
    fill_rates,
    measure_checked,
    measure_structured,
    speed_ratios,
)
from riskplan.tissue_planning.plan import (
    SELECTIONS,
    STEP_S,
    TissuePlanningResult,
    check_tissue_budget,
    plan_tissue,
    selection_setup,
)
from riskplan.tissue_planning.rrt import (
    RRTOptions,
    TreeResult,
    actuation_std,
    grow_tree,
    planning_space,
    rrt_plans,
    sampling_bounds,
)
from riskplan.tissue_planning.select import (
    PlanScore,
    Selection,
    common_draws,
    evaluate_plan,
    select_plan,
    tie_note,
)

__all__ = [
    "SATURATED",
    "SELECTIONS",
    "STEP_S",
    "Calibration",
    "CalibrationRow",
    "PlanScore",
    "RRTOptions",
    "Selection",
    "TissuePlanningResult",
    "TreeResult",
    "actuation_std",
    "calibration_check",
    "calibration_metrics",
    "check_tissue_budget",
    "common_draws",
    "evaluate_plan",
    "evenly_spaced_ranks",
    "grow_tree",
    "plan_tissue",
    "planning_space",
    "rrt_plans",
    "sampling_bounds",
    "select_plan",
    "selection_setup",
    "tie_note",
]

# the 3-D needle's planning (needle3d.py, needle3d_checks.py)
__all__ += [
    "CHECK_POINTS",
    "DRAWS_PER_TASK",
    "ESTIMATORS",
    "GOAL_SE",
    "MAX_GOAL_SAMPLES",
    "MAX_PARTICLES",
    "PARTICLES_BATCH",
    "PARTICLES_SE",
    "Needle3DResult",
    "PlanRow",
    "accuracy_checks",
    "evaluate_candidates",
    "execute_draws",
    "fill_rates",
    "measure_checked",
    "measure_plan",
    "measure_structured",
    "plan_needle3d",
    "speed_ratios",
]
