"""Control under uncertainty for the deformable-planning method (Patil, van den Berg &
Alterovitz, RSS 2011, section IV-B..D): the nominal plan, numerical linearisation,
finite-horizon LQR, Kalman filter, closed-loop LQG execution and LQG-MP.

Depends only on the :class:`~riskplan.scenarios.base.Simulator` protocol, NumPy/SciPy and
:mod:`riskplan.collision`.
"""

from riskplan.control.kalman import kalman_gains
from riskplan.control.linearize import Disturbance, Linearization, linearize
from riskplan.control.lqg import (
    Execution,
    LQGController,
    SuccessEstimate,
    augmented_model,
    bryson_weights,
    execute,
    lqg_controller,
    monte_carlo_success,
)
from riskplan.control.lqgmp import LQGMPResult, lqgmp
from riskplan.control.lqr import lqr_gains
from riskplan.control.plan import NominalPlan

__all__ = [
    "Disturbance",
    "Execution",
    "LQGController",
    "LQGMPResult",
    "Linearization",
    "NominalPlan",
    "SuccessEstimate",
    "augmented_model",
    "bryson_weights",
    "execute",
    "kalman_gains",
    "linearize",
    "lqg_controller",
    "lqgmp",
    "lqr_gains",
    "monte_carlo_success",
]
