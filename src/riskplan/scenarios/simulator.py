"""Backwards-compatible re-export of the simulator seam.

The protocol, parameters, states and helpers live in :mod:`riskplan.scenarios.base`; the
name → scenario registry in :mod:`riskplan.scenarios.registry`. Existing imports from
``riskplan.scenarios.simulator`` keep working.
"""

from __future__ import annotations

from riskplan.scenarios.base import (  # noqa: F401
    FEMScenario,
    SimParams,
    SimState,
    Simulator,
    actuation_noise,
    apply_actuation_noise,
    check_control,
    frozen_array,
    gaussian_noise,
    rollout,
)
from riskplan.scenarios.registry import SCENARIO_NAMES, make_scenario

__all__ = [
    "SCENARIO_NAMES",
    "FEMScenario",
    "SimParams",
    "SimState",
    "Simulator",
    "actuation_noise",
    "frozen_array",
    "make_scenario",
    "rollout",
]
