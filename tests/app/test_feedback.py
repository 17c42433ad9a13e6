"""Open vs closed loop on common draws (riskplan.app.reproduce.feedback): the conditions'
parameter draws, the paired summary, and one small batch on the manipulation scenario."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.app.reproduce.feedback import (
    CONDITIONS,
    condition_params,
    feedback_batch,
    paired_summary,
)
from riskplan.errors import InvalidInputError
from riskplan.scenarios.registry import make_scenario
from tests.conftest import TOL


def test_condition_draws():
    sim = make_scenario("manipulation", "material-high")
    gen = np.random.default_rng(0)
    draws = [condition_params("fig7cd", sim, gen) for _ in range(4000)]
    e = np.array([d.youngs_modulus for d in draws])
    nu = np.array([d.poissons_ratio for d in draws])
    # E ~ N(35, 75), ν ~ N(0.4, 4e-4): sample moments within 4 standard errors
    assert abs(e.mean() - 35.0) < 4 * np.sqrt(75.0 / len(e))
    assert abs(e.var() / 75.0 - 1) < 4 * np.sqrt(2.0 / len(e))
    assert abs(nu.mean() - 0.4) < 4 * np.sqrt(4e-4 / len(e))
    assert all(d.n_elements == sim.nominal_params.n_elements for d in draws)
    p = condition_params("fig7ef", sim, gen)
    assert p.n_elements == 1000 and p.youngs_modulus == sim.nominal_params.youngs_modulus
    assert {c.case for c in CONDITIONS.values() if c.scenario == "manipulation"} == {
        "material-high",
        "mesh",
    }
    with pytest.raises(InvalidInputError, match="figure"):
        condition_params("fig9", sim, gen)


def test_paired_summary_counts_pairs():
    rows = [
        [1, 0, 0, 1, 0, 0, ""],
        [0, 1, 0, 1, 0, 0, ""],
        [0, 1, 0, 1, 0, 0, ""],
        [1, 0, 0, 0, 1, 0, ""],
        [0, 0, 1, 0, 0, 1, "solver failed"],
    ]
    s = paired_summary(rows)
    assert s["open"]["successes"] == 2 and s["closed"]["successes"] == 3
    assert s["open"]["collided"] == 2 and s["closed"]["collided"] == 1
    assert s["open"]["solver_failed"] == s["closed"]["solver_failed"] == 1
    assert s["pairs"] == {"both": 1, "closed_only": 2, "open_only": 1, "neither": 1}
    np.testing.assert_allclose(s["difference"], 0.2, **TOL["float64_exact"])
    assert s["open"]["low"] < 0.4 < s["open"]["high"]
    assert s["first_error"] == "solver failed"


def test_batch_runs_open_and_closed_on_the_same_draws():
    # without a controller both halves of every row are the same execution
    from riskplan.control import NominalPlan
    from riskplan.scenarios.base import SimParams

    sim = make_scenario("manipulation", "material-high")
    u = np.tile([-0.2, 0.1, -0.1, -0.1, 0.1, -0.2], (2, 1))
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u, SimParams())
    rows = feedback_batch((sim, plan, None, "fig7cd", [1, 2, 3]))
    assert len(rows) == 3
    for r in rows:
        assert r[:3] == r[3:6]


def test_needle_conditions_fixed_in_advance():
    """Figs. 4 and 5 of the needle: the actuation case's draws, and E fixed at the values of
    needle_study.FIG5_YOUNGS with the planning parameters otherwise."""
    from riskplan.app.reproduce.needle_study import FIG5_YOUNGS

    act = make_scenario("needle", "actuation")
    p = condition_params("fig4", act, np.random.default_rng(0))
    assert p == act.distribution.sample(np.random.default_rng(0))
    assert p.actuation_cov is not None
    sim = make_scenario("needle", "material-high")
    stiff = [condition_params(f, sim, np.random.default_rng(1)) for f in ("fig5", "fig5-67")]
    assert tuple(s.youngs_modulus for s in stiff) == FIG5_YOUNGS
    for s in stiff:
        assert s.replace(youngs_modulus=sim.nominal_params.youngs_modulus) == sim.nominal_params
    assert {CONDITIONS[f].case for f in ("fig4", "fig5", "fig5-67")} == {
        "actuation",
        "material-high",
    }
