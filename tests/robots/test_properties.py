"""Property-based tests of the robot entry points (see tests/properties.py for the contract)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from riskplan.robots import load_robot
from riskplan.robots.description import parse_robot_toml
from tests.conftest import TOL
from tests.properties import PROPERTY, any_float, arrays_or_junk, assert_finite, call, junk

ROBOT = load_robot("paper")
LIMITS = np.asarray(ROBOT.displacement_limits)


@PROPERTY
@given(d=arrays_or_junk(hnp.array_shapes(min_dims=0, max_dims=2, min_side=0, max_side=5)))
def test_solve_displacements_arbitrary(d):
    s = call(ROBOT.solve_displacements, d)
    if s is not None:
        assert_finite(s.positions, s.tensions)
        assert np.all(
            np.linalg.norm(s.positions, axis=-1) <= 0.2 * 1.01 + TOL["solver"]["atol"]
        )  # never beyond the 0.2 m rod


@PROPERTY
@given(
    t=arrays_or_junk(
        hnp.array_shapes(min_dims=1, max_dims=2, min_side=4, max_side=4), st.floats(-1, 20)
    )
)
def test_solve_tensions_arbitrary(t):
    s = call(ROBOT.solve_tensions, t)
    if s is not None:
        assert_finite(s.positions)


@PROPERTY
@given(
    length=st.one_of(any_float, junk()),
    step=st.one_of(any_float, junk()),
    radius=st.one_of(any_float, junk()),
    limits=st.lists(any_float, min_size=0, max_size=3),
    count=st.one_of(st.integers(-3, 10**9), junk()),
)
def test_robot_descriptions_arbitrary(length, step, radius, limits, count):
    def fmt(v):
        return (
            repr(v).replace("inf", "inf").replace("None", '"none"')
            if not isinstance(v, str)
            else f'"{v!r}"'
        )

    text = (
        f"[backbone]\nlength = {fmt(length)}\nouter_radius = 0.002\nyoungs_modulus = 2e8\nstep = {fmt(step)}\n"
        f"[disks]\ncount = {fmt(count)}\n"
        f"[[tendons]]\ntheta = [0.0]\nradius = [{fmt(radius)}]\ndisplacement_limits = {limits!r}\nmax_tension = 5.0\n"
    )
    p = call(parse_robot_toml, text)
    if p is not None:
        assert p.backbone.n_steps <= 20_000
        assert_finite(p.backbone.length, p.backbone.step)
