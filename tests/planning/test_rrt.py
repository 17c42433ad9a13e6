"""Simulator RRT (paper IV-A): plans replay bit for bit, are collision-free, end in the
deformed goal, are distinct, do not depend on the backend; the error paths are named."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskplan.control import NominalPlan
from riskplan.errors import InvalidInputError, PlanningError
from riskplan.planning.rrt import PlanningSpace, RRTOptions, grow_tree, planning_space, rrt_plans
from riskplan.scenarios.manipulation import ManipulationScenario
from tests.planning.conftest import SMALL_MESH, PointRobot



def _check_plan(sim, plan, params):
    assert isinstance(plan, NominalPlan)
    # re-simulated from the root with its controls: the stored states, bit for bit
    replay = NominalPlan.from_rollout(sim, sim.initial_state(params), plan.controls, params)
    assert all(a.identical(b) for a, b in zip(plan.states, replay.states))
    assert plan.reduced.tobytes() == replay.reduced.tobytes()
    space = planning_space(sim)
    for t, st in enumerate(plan.states):
        assert not sim.in_collision(st), f"collision at step {t}"
        assert space.contains(plan.reduced[t])
        # an edge ends at its first state in the goal: only the last state is in it
        assert sim.in_goal(st) == (t == plan.n_steps)
    lo, hi = sim.control_bounds[:, 0], sim.control_bounds[:, 1]
    assert np.all((plan.controls >= lo) & (plan.controls <= hi))


def test_needle_plans_replay_collision_free_in_goal(near_needle, needle_result):
    plans, trees = needle_result
    assert len(plans) == 4 and len(trees) == 2
    for plan in plans:
        _check_plan(near_needle, plan, SMALL_MESH)
        assert plan.params == SMALL_MESH
    # distinct candidates
    keys = {p.controls.tobytes() for p in plans}
    assert len(keys) == len(plans)
    # the tree records: root first, parents point backwards, goal nodes are leaves
    for tree in trees:
        assert tree.parents[0] == -1 and np.all(tree.parents[1:] < np.arange(1, tree.size))
        assert not set(tree.goal_nodes) & set(tree.parents.tolist())
        assert tree.best_goal_distance <= near_needle.config.goal_radius


def test_obstacle_deformed_check_is_used(near_needle, needle_result):
    # the plans pass the obstacle, whose deformed polygon differs from the reference one
    plans, _ = needle_result
    moved = [np.abs(near_needle.obstacles(s)[0] - near_needle.config.obstacles[0]).max() for s in plans[0].states[1:]]
    assert max(moved) > 1e-3


def test_same_seed_same_plans_on_serial_and_local(point_robot):
    opts = RRTOptions(plans_per_tree=2)
    plans, _ = rrt_plans(point_robot, 6, seed=3, options=opts, backend="serial")
    again, _ = rrt_plans(point_robot, 6, seed=3, options=opts, backend="local", workers=2)
    assert [p.controls.tobytes() for p in again] == [p.controls.tobytes() for p in plans]
    other, _ = rrt_plans(point_robot, 2, seed=4, options=opts, backend="serial")
    assert other[0].controls.tobytes() != plans[0].controls.tobytes()


def test_grow_tree_deterministic(point_robot):
    a = grow_tree(point_robot, seed=11, options=RRTOptions(plans_per_tree=3))
    b = grow_tree(point_robot, seed=11, options=RRTOptions(plans_per_tree=3))
    assert a.nodes.tobytes() == b.nodes.tobytes() and a.goal_nodes == b.goal_nodes


def test_user_simulator_with_its_own_space(point_robot):
    plans, trees = rrt_plans(point_robot, 5, seed=0, options=RRTOptions(plans_per_tree=5), backend="serial")
    assert len(plans) == 5 and len(trees) == 1
    for plan in plans:
        _check_plan(point_robot, plan, point_robot.nominal_params)


def test_manipulation_plan(tmp_path):
    sim = ManipulationScenario()
    params = sim.nominal_params.replace(n_elements=60)
    tree = grow_tree(sim, seed=1, params=params, options=RRTOptions(plans_per_tree=1, max_iterations=300))
    assert len(tree.plans) == 1
    plan = tree.plans[0]
    _check_plan(sim, plan, params)
    # consecutive controls respect the scenario's rate limit
    space = planning_space(sim)
    steps = np.abs(np.diff(np.vstack([np.zeros(6), plan.controls]), axis=0))
    assert np.all(steps <= space.max_control_change + 1e-12)


def test_no_plan_raises_planning_error_with_tree_size_and_distance():
    # the goal is walled in by the obstacle: unreachable
    sim = PointRobot(goal=(0.5, 0.5), goal_radius=0.05, obstacle=((0.3, 0.3), (0.7, 0.7)))
    with pytest.raises(PlanningError, match=r"tree sizes \d+\.\.\d+ nodes, best goal distance 0\.\d+"):
        rrt_plans(sim, 3, seed=0, options=RRTOptions(max_iterations=40, plans_per_tree=3), max_rounds=1, backend="serial")


def test_fewer_plans_than_asked_returns_what_was_found(point_robot, caplog):
    plans, trees = rrt_plans(
        point_robot, 6, seed=2, options=RRTOptions(max_iterations=40, plans_per_tree=3), max_rounds=1, backend="serial"
    )
    assert 1 <= len(plans) < 6 and len(trees) == 2
    assert "plans within the budget" in caplog.text


def test_distance_metric_against_a_loop(rng, tol):
    space = PlanningSpace(low=[0, 0, -math.pi], high=[1, 1, math.pi], weights=[1, 4, 0.01],
                          periodic=[False, False, True], goal=[0.5, 0.5, 0])
    xs = rng.uniform(-4, 4, (20, 3))
    x = rng.uniform(-4, 4, 3)
    want = [math.sqrt((a[0] - x[0]) ** 2 + 4 * (a[1] - x[1]) ** 2
                      + 0.01 * math.remainder(a[2] - x[2], 2 * math.pi) ** 2) for a in xs]
    np.testing.assert_allclose(space.distance(xs, x), want, **tol["float64_ref"])
    # towards the goal the heading is ignored
    want_goal = [math.sqrt((a[0] - 0.5) ** 2 + 4 * (a[1] - 0.5) ** 2) for a in xs]
    np.testing.assert_allclose(space.distance(xs, space.goal, to_goal=True), want_goal, **tol["float64_ref"])


def test_bad_input_is_named(point_robot):
    with pytest.raises(InvalidInputError, match="weights"):
        PlanningSpace(low=[0, 0], high=[1, 1], weights=[0, 0], periodic=[False, False], goal=[0, 0])
    with pytest.raises(InvalidInputError, match="steps_per_extension"):
        PlanningSpace(low=[0], high=[1], weights=[1], periodic=[False], goal=[0], steps_per_extension=0)
    with pytest.raises(InvalidInputError, match="n_plans"):
        rrt_plans(point_robot, 0)
    with pytest.raises(InvalidInputError, match="goal_bias"):
        RRTOptions(goal_bias=1.5)

    class NoGoal:
        pass

    with pytest.raises(InvalidInputError, match="in_goal|lacks"):
        rrt_plans(NoGoal(), 1)
    with pytest.raises(InvalidInputError, match="planning space"):
        planning_space(object())
