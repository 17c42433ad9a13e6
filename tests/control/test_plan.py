"""NominalPlan: built from a rollout, read-only, picklable, validated."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from riskplan.control import NominalPlan
from riskplan.errors import InvalidInputError
from riskplan.scenarios.needle import NeedleScenario


def test_from_rollout_reproduces_states():
    sim = NeedleScenario()
    u = sim.random_controls(6, seed=3)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    assert plan.n_steps == 6 and len(plan.states) == 7
    assert (
        plan.reduced.shape == (7, 3)
        and not plan.reduced.flags.writeable
        and not plan.controls.flags.writeable
    )
    s = sim.initial_state()
    for t in range(6):
        s = sim.step(s, u[t])
        assert s.identical(plan.states[t + 1])
        np.testing.assert_array_equal(plan.reduced[t + 1], sim.reduced(s))
    clone = pickle.loads(pickle.dumps(plan))
    assert not clone.controls.flags.writeable and clone.states[-1].identical(plan.states[-1])


def test_validation():
    sim = NeedleScenario()
    with pytest.raises(InvalidInputError, match="controls"):
        NominalPlan.from_rollout(sim, sim.initial_state(), np.zeros((3, 3)))
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), sim.random_controls(2, seed=1))
    with pytest.raises(InvalidInputError, match="states"):
        NominalPlan(
            states=plan.states[:2], controls=plan.controls, reduced=plan.reduced, params=plan.params
        )
