"""The name → scenario registry (:func:`make_scenario`, :data:`SCENARIO_NAMES`).

Kept apart from :mod:`riskplan.scenarios.base` so the module the scenarios import never
imports the scenarios back.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

from riskplan.errors import InvalidInputError

__all__ = ["SCENARIO_NAMES", "load_scenario_file", "make_scenario", "scenario_from_config"]

#: Names accepted by :func:`make_scenario` (and the CLI ``--scenario`` option).
SCENARIO_NAMES = ("needle", "manipulation")


def make_scenario(name: str, case: str = "nominal"):
    """The scenario ``name`` (:data:`SCENARIO_NAMES`, or the path of a scenario file,
    :mod:`riskplan.scenarios.files`) with the parameter distribution of uncertainty
    ``case`` (:data:`riskplan.scenarios.uncertainty.CASE_NAMES`) as its S; each scenario
    gets its own actuation covariance (``sim.actuation_cov()``)."""
    if name == "needle":
        from riskplan.scenarios.needle import NeedleConfig

        return scenario_from_config("needle", NeedleConfig(), case)
    if name == "manipulation":
        from riskplan.scenarios.manipulation import ManipulationConfig

        return scenario_from_config("manipulation", ManipulationConfig(), case)
    if isinstance(name, str | PathLike) and (str(name).endswith(".toml") or Path(name).is_file()):
        return load_scenario_file(name, case)
    raise InvalidInputError(
        f"scenario: expected one of {', '.join(SCENARIO_NAMES)} or a scenario file (.toml), "
        f"got {name!r}"
    )


def scenario_from_config(kind: str, config, case: str = "nominal"):
    """The scenario of ``kind`` (``"needle"`` or ``"manipulation"``) built on ``config``,
    with the distribution of ``case`` around its nominal parameters and its own actuation
    covariance."""
    from riskplan.scenarios.uncertainty import get_case

    if kind == "needle":
        from riskplan.scenarios.needle import NeedleScenario

        sim = NeedleScenario(config)
    elif kind == "manipulation":
        from riskplan.scenarios.manipulation import ManipulationScenario

        sim = ManipulationScenario(config)
    else:
        raise InvalidInputError(f"kind: expected one of {', '.join(SCENARIO_NAMES)}, got {kind!r}")
    sim.distribution = get_case(case, sim.nominal_params, actuation_cov=sim.actuation_cov())
    return sim


def load_scenario_file(path, case: str = "nominal"):
    """The scenario of a file (:func:`~riskplan.scenarios.files.read_scenario_config`) with
    the parameter distribution of uncertainty ``case`` as its S (as :func:`make_scenario`)."""
    from riskplan.scenarios.files import read_scenario_config

    kind, cfg = read_scenario_config(path)
    return scenario_from_config(kind, cfg, case)
