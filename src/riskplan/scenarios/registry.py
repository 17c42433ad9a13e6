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
SCENARIO_NAMES = ("needle", "manipulation", "needle3d")


def make_scenario(name: str, case: str = "nominal"):
    """The scenario ``name`` with the parameter distribution of uncertainty ``case`` as its S.

    Each scenario gets its own actuation covariance (``sim.actuation_cov()``).

    Parameters
    ----------
    name : str
        One of :data:`SCENARIO_NAMES`, or the path of a scenario file
        (:mod:`riskplan.scenarios.files`).
    case : str
        One of :data:`riskplan.scenarios.uncertainty.CASE_NAMES`.

    Returns
    -------
    Simulator
        The scenario, with the case's parameter distribution.
    """
    if name == "needle":
        from riskplan.scenarios.needle import NeedleConfig

        return scenario_from_config("needle", NeedleConfig(), case)
    if name == "manipulation":
        from riskplan.scenarios.manipulation import ManipulationConfig

        return scenario_from_config("manipulation", ManipulationConfig(), case)
    if name == "needle3d":
        return scenario_from_config("needle3d", None, case)
    if isinstance(name, str | PathLike) and (str(name).endswith(".toml") or Path(name).is_file()):
        return load_scenario_file(name, case)
    raise InvalidInputError(
        f"scenario: expected one of {', '.join(SCENARIO_NAMES)} or a scenario file (.toml), "
        f"got {name!r}"
    )


def scenario_from_config(kind: str, config, case: str = "nominal"):
    """The scenario of ``kind`` built on ``config``, with the distribution of ``case`` around its
    nominal parameters and its own actuation covariance.

    Parameters
    ----------
    kind : str
        ``"needle"``, ``"manipulation"`` or ``"needle3d"``.
    config : object or None
        The kind's configuration (``None``: the default).
    case : str
        An uncertainty case name.

    Returns
    -------
    Simulator
        The scenario.
    """
    from riskplan.scenarios.uncertainty import get_case

    if kind == "needle":
        from riskplan.scenarios.needle import NeedleScenario

        sim = NeedleScenario(config)
    elif kind == "manipulation":
        from riskplan.scenarios.manipulation import ManipulationScenario

        sim = ManipulationScenario(config)
    elif kind == "needle3d":
        from riskplan.scenarios.needle3d import Needle3DScenario

        sim = Needle3DScenario(config)
        if case == "mesh":
            from riskplan.scenarios.uncertainty import MeshUncertainty

            # the 2-D paper draws 50..1000 triangles around a 175-triangle planning mesh; in
            # 3-D the counts are tetrahedra around the 1296 of the planning mesh, up to the
            # 5000 SimParams allows (grids of 4 to 9 cells per axis)
            sim.distribution = MeshUncertainty(base=sim.nominal_params, low=400, high=5000)
            return sim
    else:
        raise InvalidInputError(f"kind: expected one of {', '.join(SCENARIO_NAMES)}, got {kind!r}")
    sim.distribution = get_case(case, sim.nominal_params, actuation_cov=sim.actuation_cov())
    return sim


def load_scenario_file(path, case: str = "nominal"):
    """The scenario of a file (:func:`~riskplan.scenarios.files.read_scenario_config`) with the
    parameter distribution of uncertainty ``case`` as its S (as :func:`make_scenario`).

    Parameters
    ----------
    path : str or path
        A scenario TOML file.
    case : str
        An uncertainty case name.

    Returns
    -------
    Simulator
        The scenario.
    """
    from riskplan.scenarios.files import read_scenario_config

    kind, cfg = read_scenario_config(path)
    return scenario_from_config(kind, cfg, case)
