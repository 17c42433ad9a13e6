"""Needle studies: feedback against open loop on common draws where the mechanism says it
should help (actuation noise) and where it says it cannot (a stiffer material: the tissue
carries the robot and the embedded goal alike), the case variants, deformation sizes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskplan.app.reproduce.deformable import open_closed_rates
from riskplan.app.reproduce.needle_study import deformation_sizes, needle_variant
from riskplan.control import NominalPlan, linearize, lqg_controller
from riskplan.errors import InvalidInputError
from riskplan.parallel import spawn_seeds
from riskplan.scenarios.base import rollout
from riskplan.scenarios.needle import NeedleConfig, NeedleScenario
from riskplan.scenarios.uncertainty import get_case
from tests.conftest import TOL

N = 60


@pytest.fixture(scope="module")
def arc():
    """A 14-step arc whose end (material point) is the centre of a small goal, no obstacles."""
    u = np.tile([0.4, 0.15], (14, 1))
    free = NeedleScenario()
    end = rollout(free, free.initial_state(), u)[-1]
    sim = NeedleScenario(
        NeedleConfig(goal_center=tuple(end.material[:2]), goal_radius=0.025, obstacles=())
    )
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    assert sim.in_goal(plan.states[-1])
    return sim, plan


def _controller(sim, plan, case):
    sim.distribution = get_case(case, sim.nominal_params)
    return lqg_controller(linearize(sim, plan, sim.distribution, n_samples=16, seed=0))


def test_feedback_rescues_runs_under_actuation_noise(arc):
    """Actuation noise moves the robot through the material: the loop senses it and steers
    back. Same draws (noise sequence and sensing) open and closed."""
    sim, plan = arc
    ctrl = _controller(sim, plan, "actuation")
    seeds = spawn_seeds(3, N)
    params = [sim.distribution.sample(np.random.default_rng([s, 1])) for s in seeds]
    r = open_closed_rates(sim, plan, ctrl, params, seeds)
    assert r["open"] < N  # the counterfactual: open loop misses some
    assert r["closed"] > r["open"]
    assert r["only_closed"] >= 3 * max(1, r["only_open"]), r
    assert sum(r["open_outcomes"].values()) == sum(r["closed_outcomes"].values()) == N


def test_stiffer_material_cannot_make_open_loop_miss(arc):
    """E = 150 instead of 50: the material path of an open-loop run is the plan's and the
    goal is embedded in the same tissue, so open loop succeeds every time; the closed loop
    reads the smaller world offset as a deviation of the robot and steers away from it."""
    sim, plan = arc
    ctrl = _controller(sim, plan, "material-high")
    stiff = sim.nominal_params.replace(youngs_modulus=150.0)
    r = open_closed_rates(sim, plan, ctrl, [stiff] * N, spawn_seeds(4, N))
    assert r["open"] == N
    assert r["closed"] < N and r["only_closed"] == 0


def test_needle_variants():
    make = needle_variant(actuation_scale=2.0, force_scale=0.5)
    act = make("needle", "actuation")
    np.testing.assert_allclose(
        np.asarray(act.distribution.cov),
        np.diag([4 * 0.05**2, 4 * math.radians(5.0) ** 2]),
        **TOL["float64_exact"],
    )
    assert act.nominal_params.force_scale == 0.5
    force = make("needle", "force")
    assert force.distribution.high == 1.0 and force.nominal_params.force_scale == 0.5
    every = needle_variant(actuation_everywhere=True)("needle", "mesh")
    assert every.distribution.name == "mesh+actuation"
    assert every.distribution.sample(0).actuation_cov is not None
    assert every.nominal_params.actuation_cov is None
    with pytest.raises(InvalidInputError, match="needle"):
        make("manipulation", "mesh")
    with pytest.raises(InvalidInputError, match="force_scale"):
        needle_variant(force_scale=0.0)


def test_deformation_sizes_follow_the_force(arc):
    """At the end of a plan: the robot's offset and the goal centre's displacement; under
    the force case (f ~ U[0, 2]) neither exceeds twice the nominal (linear in f)."""
    _, plan = arc
    d = deformation_sizes([plan], n_draws=4, seed=0, cases=("nominal", "force"))
    nom, force = d["nominal"], d["force"]
    assert nom["runs"] == 1 and force["runs"] == 4
    assert nom["robot"][0] > 1e-3 and nom["goal_centre"][0] > 0.0
    for key in ("robot", "goal_centre", "obstacles"):
        assert force[key][0] <= force[key][1] <= 2 * nom[key][1] + TOL["float64_abs"]["atol"]


def test_sensitivity_at_a_tiny_scale(tmp_path):
    """Every variant runs and the table has a rate per method and factor; the actuation
    variants reuse the ×1 candidates and change only case 3; a rerun reads the stores."""
    from riskplan.app.reproduce.deformable import METHODS, ScenarioScale
    from riskplan.app.reproduce.needle_study import sensitivity

    tiny = ScenarioScale(
        n_candidates=1,
        n_executions=2,
        batch_size=2,
        lin_samples=2,
        goal_samples=50,
        plans_per_tree=1,
    )
    r = sensitivity(tiny, tmp_path, factors=(0.5, 1.0), backend="serial")
    for kind in ("actuation", "force"):
        assert set(r[kind]) == {0.5, 1.0}
        for f in (0.5, 1.0):
            assert set(r[kind][f]) == set(METHODS)
            assert all(v is None or 0.0 <= v <= 1.0 for v in r[kind][f].values())
    base, act = r["runs"]["act1_force1"], r["runs"]["act0.5_force1"]
    assert set(act["cases"]) == {"actuation"} and act["plan_steps"] == base["plan_steps"]
    assert set(r["actuation_everywhere"]) == set(METHODS)
    again = sensitivity(tiny, tmp_path, factors=(0.5, 1.0), backend="serial")
    assert again["force"] == r["force"]


def test_reproduce_sensitivity_stage(tmp_path, monkeypatch):
    """``stages=("sensitivity",)`` runs the needle's sensitivity alone into results.json
    (each variant's per-case rates beside the mean tables) and the report."""
    import json

    from riskplan.app.reproduce import pipeline as rep
    from riskplan.app.reproduce.deformable import METHODS, ScenarioScale

    tiny = ScenarioScale(
        n_candidates=1,
        n_executions=2,
        batch_size=2,
        lin_samples=2,
        goal_samples=50,
        plans_per_tree=1,
    )
    monkeypatch.setattr(rep, "_sensitivity_scales", lambda: {"smoke": tiny})
    out = tmp_path / "out"
    rep.reproduce(out, paper="deformable", stages=("sensitivity",), backend="serial")
    saved = json.loads((out / "results.json").read_text())
    sens = saved["deformable"]["needle"]["sensitivity"]
    assert set(saved["deformable"]["needle"]) == {"sensitivity"}  # the figures did not run
    assert set(sens["actuation"]) == set(sens["force"]) == {"0.5", "1.0", "2.0"}
    assert set(sens["actuation_everywhere"]) == set(METHODS)
    assert sens["scale"]["n_executions"] == 2
    assert set(sens["cases"]["act2_force1"]) == {"actuation"}  # case 3 only under our reading
    html = (out / "report.html").read_text()
    assert "needle: sensitivity" in html and "the other reading" in html
