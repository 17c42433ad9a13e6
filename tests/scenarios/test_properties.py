"""Property-based tests of the scenario entry points (see tests/properties.py for the contract)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from riskplan.planning.chest_scene import ChestParams
from riskplan.scenarios.needle import NeedleScenario
from tests.properties import PROPERTY, any_float, arrays_or_junk, assert_finite, call, junk

NEEDLE = NeedleScenario()
STATE = NEEDLE.initial_state()


@PROPERTY
@given(u=arrays_or_junk(elements=st.floats(-2, 2) | any_float))
def test_needle_step_arbitrary_controls(u):
    s = call(NEEDLE.step, STATE, u)
    if s is not None:
        assert_finite(NEEDLE.reduced(s))


@PROPERTY
@given(pose=arrays_or_junk())
def test_needle_initial_pose_arbitrary(pose):
    s = call(NEEDLE.initial_state, None, pose)
    if s is not None:
        assert_finite(NEEDLE.reduced(s))


@PROPERTY
@given(
    changes=st.fixed_dictionaries(
        {},
        optional={
            k: st.one_of(any_float, junk(), st.integers(-2, 8))
            for k in (
                "wall_thickness",
                "port_depth",
                "subdivisions",
                "shape_noise",
                "insertion_height",
            )
        },
    )
)
def test_chest_parameters_arbitrary(changes):
    p = call(ChestParams, **changes)
    if p is not None:
        call(p.validate)
