"""The name → scenario registry (:func:`make_scenario`, :data:`SCENARIO_NAMES`).

Kept apart from :mod:`riskplan.scenarios.base` so the module the scenarios import never
imports the scenarios back.
"""

from __future__ import annotations

from riskplan.errors import InvalidInputError

__all__ = ["SCENARIO_NAMES", "make_scenario"]

#: Names accepted by :func:`make_scenario` (and the CLI ``--scenario`` option).
SCENARIO_NAMES = ("needle", "manipulation")


def make_scenario(name: str, case: str = "nominal"):
    """The scenario ``name`` (:data:`SCENARIO_NAMES`) with the parameter distribution of
    uncertainty ``case`` (:data:`riskplan.scenarios.uncertainty.CASE_NAMES`) as its S;
    the manipulation scenario gets its own actuation covariance."""
    from riskplan.scenarios.uncertainty import get_case

    if name == "needle":
        from riskplan.scenarios.needle import NeedleScenario

        sim = NeedleScenario()
        sim.distribution = get_case(case, sim.nominal_params)
    elif name == "manipulation":
        from riskplan.scenarios.manipulation import ManipulationScenario

        sim = ManipulationScenario()
        sim.distribution = get_case(case, sim.nominal_params, actuation_cov=sim.actuation_cov())
    else:
        raise InvalidInputError(
            f"scenario: expected one of {', '.join(SCENARIO_NAMES)}, got {name!r}"
        )
    return sim
