"""Property-based tests of the planning entry points (see tests/properties.py for the
contract): ``interpolate_path`` and ``optimise_trajectory`` on arbitrary and structured
input, ``rrt_plans`` and ``select_plan`` on perturbations of the built-in needle scenario on
a coarse mesh (few examples: each grows trees or runs the simulator)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from riskplan.planning.bo import LIMIT_SLACK, OptimiserConfig, optimise_trajectory
from riskplan.planning.prm import interpolate_path
from riskplan.scenarios.needle import NeedleConfig, NeedleScenario
from riskplan.scenarios.uncertainty import CASE_NAMES, get_case
from riskplan.tissue_planning.rrt import RRTOptions, rrt_plans
from riskplan.tissue_planning.select import select_plan
from tests.conftest import TOL
from tests.planning.conftest import SMALL_MESH
from tests.properties import (
    PROPERTY,
    any_float,
    arrays_or_junk,
    assert_finite,
    assert_probability,
    call,
    junk,
    small_budget,  # noqa: F401  (fixture: a 32 MiB memory budget)
)


@PROPERTY
@given(path=arrays_or_junk(), step=st.one_of(any_float, junk(), st.integers(-3, 3)))
def test_interpolate_path_arbitrary(path, step):
    out = call(interpolate_path, path, step)
    if out is not None:
        assert_finite(out)
        p = np.asarray(path, dtype=np.float64)
        np.testing.assert_array_equal(out[0], p[0])
        np.testing.assert_array_equal(out[-1], p[-1])
        # consecutive configurations at most `step` apart, up to the rounding of the split
        # (relative to the step) and of the coordinates (a few ulps of the largest)
        slack = float(step) * TOL["float64_exact_rel"]["rtol"] + 8 * np.spacing(np.abs(p).max())
        assert np.all(np.linalg.norm(np.diff(out, axis=0), axis=-1) <= float(step) + slack)


class Free:
    def __call__(self, c):
        return np.ones(len(np.atleast_2d(c)), dtype=bool)

    def motions(self, a, b, resolution):
        return np.ones(len(np.atleast_2d(a)), dtype=bool)


def bump(c):
    c = np.atleast_2d(c)
    return 0.01 + 0.4 * np.exp(-np.sum((c - 0.5) ** 2, axis=-1) / 0.05)


scale_floats = st.one_of(any_float, st.floats(-2, 2), st.sampled_from([0.0, 1e-300, 1e300]))


@settings(PROPERTY, max_examples=60)
@given(
    traj=st.one_of(
        hnp.arrays(
            np.float64, st.tuples(st.integers(0, 4), st.just(2)), elements=st.floats(0, 1e-3)
        ),
        hnp.arrays(np.float64, st.tuples(st.integers(0, 4), st.just(2)), elements=scale_floats),
        arrays_or_junk(elements=scale_floats),
    ),
    limits=st.one_of(
        st.just(np.array([[0.0, 1.0], [-1.0, 1e-3]])),
        hnp.arrays(np.float64, (2, 2), elements=scale_floats),
        arrays_or_junk(elements=scale_floats),
    ),
    iterations=st.integers(0, 2),
    candidates=st.integers(1, 8),
    radius=st.floats(0.01, 0.5),
    method=st.sampled_from(["random", "trust_region", "sgd"]),
)
def test_optimise_trajectory_arbitrary(traj, limits, iterations, candidates, radius, method):
    cfg = call(
        OptimiserConfig,
        iterations=iterations,
        n_candidates=candidates,
        radius=radius,
        method=method,
    )
    res = call(optimise_trajectory, traj, bump, Free(), limits, config=cfg)
    if res is not None:
        lim = np.asarray(limits, dtype=np.float64)
        assert_finite(res.trajectory, res.bounds, res.trace)
        assert_probability([res.bound, res.initial_bound, *res.trace, *res.bounds])
        assert res.bound <= res.initial_bound
        slack = LIMIT_SLACK * (lim[:, 1] - lim[:, 0])  # what the optimiser accepts
        assert np.all(res.trajectory >= lim[:, 0] - slack)
        assert np.all(res.trajectory <= lim[:, 1] + slack)


@PROPERTY
@given(
    traj=hnp.arrays(np.float64, st.tuples(st.integers(2, 5), st.just(2)), elements=st.floats(0, 1)),
    iterations=st.integers(1, 3),
    method=st.sampled_from(["bo", "random", "trust_region"]),
)
def test_optimise_trajectory_valid_problems(traj, iterations, method):
    """Structured input: always a result, within the limits, never worse than the start."""
    res = optimise_trajectory(
        traj,
        bump,
        Free(),
        np.array([[0.0, 1.0], [0.0, 1.0]]),
        config=OptimiserConfig(iterations=iterations, n_candidates=8, method=method),
    )
    assert_probability([res.bound, *res.bounds])
    assert res.bound <= res.initial_bound
    assert np.all((res.trajectory >= 0) & (res.trajectory <= 1))
    np.testing.assert_array_equal(res.trajectory[[0, -1]], traj[[0, -1]])


# ---- simulator-driven: the needle scenario on a 60-element mesh --------------------------------

SIM_PROPERTY = settings(PROPERTY, max_examples=5)


@st.composite
def near_goals(draw):
    """The needle scenario with its goal moved: near the start (reachable in a few hundred
    iterations) or somewhere in the plane (often out of the small budget)."""
    cx = draw(st.floats(0.35, 0.9))
    cy = draw(st.floats(0.35, 0.9))
    r = draw(st.floats(0.04, 0.15))
    return NeedleScenario(NeedleConfig(goal_center=(cx, cy), goal_radius=r))


@PROPERTY
@given(n=st.one_of(st.integers(-3, 0), junk()), goal_bias=any_float, iterations=junk())
def test_rrt_plans_bad_arguments(n, goal_bias, iterations):
    """Arguments of the wrong type or range: a named error before any tree grows."""
    sim = NeedleScenario()
    call(rrt_plans, sim, n, params=SMALL_MESH, backend="serial")
    options = call(RRTOptions, goal_bias=goal_bias, max_iterations=iterations)
    if options is not None:
        call(rrt_plans, sim, 1, params=SMALL_MESH, options=options, backend="serial")


@SIM_PROPERTY
@given(
    sim=near_goals(),
    n=st.integers(1, 2),
    seed=st.integers(0, 2**31),
    iterations=st.integers(1, 300),
    n_controls=st.integers(1, 6),
    goal_bias=st.floats(0, 1),
)
def test_rrt_plans_perturbed_needle(sim, n, seed, iterations, n_controls, goal_bias):
    options = RRTOptions(
        plans_per_tree=1, max_iterations=iterations, n_controls=n_controls, goal_bias=goal_bias
    )
    out = call(
        rrt_plans,
        sim,
        n,
        seed=seed,
        params=SMALL_MESH,
        options=options,
        backend="serial",
        max_rounds=1,
    )
    if out is not None:
        plans, _ = out
        assert len(plans) <= n
        for plan in plans:
            assert_finite(plan.reduced, plan.controls)
            assert sim.in_goal(plan.states[-1])


@SIM_PROPERTY
@given(
    case=st.sampled_from(CASE_NAMES),
    method=st.sampled_from(["sigma", "truncation", "sampling"]),
    n_samples=st.integers(1, 3),
    seed=st.integers(0, 2**31),
)
def test_select_plan_perturbed_needle(needle_result, near_needle, case, method, n_samples, seed):
    plans = needle_result[0][:2]
    sel = call(
        select_plan,
        near_needle,
        plans,
        get_case(case, base=SMALL_MESH),
        method=method,
        n_samples=n_samples,
        n_goal_samples=50,
        seed=seed,
        backend="serial",
    )
    if sel is not None:
        assert 0 <= sel.best < len(plans)
        for s in sel.ranking:
            assert_probability([s.p_success, s.p_collision_free, s.p_goal])
