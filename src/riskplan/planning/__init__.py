"""Risk-aware motion planning with learned kinematics (MDN paper, section V)."""

from riskplan.planning.validate import (
    MixtureMonteCarlo,
    RobotMonteCarlo,
    execute_on_robot,
    mixture_monte_carlo,
    tube_clearance,
    validation_table,
)

__all__ = ["MixtureMonteCarlo", "RobotMonteCarlo", "execute_on_robot", "mixture_monte_carlo", "tube_clearance", "validation_table"]
