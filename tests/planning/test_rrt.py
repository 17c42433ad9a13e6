"""Simulator RRT (paper IV-A): plans replay bit for bit, are collision-free, end in the
deformed goal, are distinct, do not depend on the backend; the error paths are named."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from riskplan.control import NominalPlan
from riskplan.errors import InvalidInputError, PlanningError
from riskplan.scenarios.manipulation import ManipulationScenario
from riskplan.scenarios.space import BoxSpace
from riskplan.tissue_planning.rrt import (
    RRTOptions,
    grow_tree,
    planning_space,
    rrt_plans,
    sampling_bounds,
)
from tests.conftest import TOL
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
        # an edge ends at its first state in the tightened goal: only the last state is in it
        assert _in_tight_goal(sim, st) == (t == plan.n_steps)
    lo, hi = sim.control_bounds[:, 0], sim.control_bounds[:, 1]
    assert np.all((plan.controls >= lo) & (plan.controls <= hi))


def _in_tight_goal(sim, st, depth=RRTOptions().goal_depth):
    r = getattr(sim, "goal_radius", None) or sim.config.goal_radius
    return sim.in_goal(st) and sim.goal_distance(st) <= (1.0 - depth) * r


def test_needle_plans_replay_collision_free_in_goal(near_needle, needle_result):
    plans, trees = needle_result
    # two plans per tree: at least two trees (more if a tree's budget found fewer)
    assert len(plans) == 4 and 2 <= len(trees) <= 4
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
    moved = [
        np.abs(near_needle.obstacles(s)[0] - near_needle.config.obstacles[0]).max()
        for s in plans[0].states[1:]
    ]
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
    plans, trees = rrt_plans(
        point_robot, 5, seed=0, options=RRTOptions(plans_per_tree=5), backend="serial"
    )
    assert len(plans) == 5 and len(trees) == 1
    for plan in plans:
        _check_plan(point_robot, plan, point_robot.nominal_params)


def test_manipulation_plan(tmp_path):
    sim = ManipulationScenario()
    params = sim.nominal_params.replace(n_elements=60)
    tree = grow_tree(
        sim, seed=1, params=params, options=RRTOptions(plans_per_tree=1, max_iterations=300)
    )
    assert len(tree.plans) == 1
    plan = tree.plans[0]
    _check_plan(sim, plan, params)
    # the controls are force increments inside the sampling bounds (the rate limit), and
    # the forces of the states are their running sum
    bounds = sampling_bounds(sim, RRTOptions())
    assert np.all(np.abs(plan.controls) <= bounds[:, 1] + TOL["float64_abs"]["atol"])
    f = np.zeros(sim.control_dim)
    for du in plan.controls:
        f = np.clip(f + du, -sim.config.f_max, sim.config.f_max)
    np.testing.assert_allclose(plan.states[-1].forces.ravel(), f, **TOL["float64_exact"])


def test_no_plan_raises_planning_error_with_tree_size_and_distance():
    # the goal is walled in by the obstacle: unreachable
    sim = PointRobot(goal=(0.5, 0.5), goal_radius=0.05, obstacle=((0.3, 0.3), (0.7, 0.7)))
    with pytest.raises(
        PlanningError, match=r"tree sizes \d+\.\.\d+ nodes, best goal distance 0\.\d+"
    ):
        rrt_plans(
            sim,
            3,
            seed=0,
            options=RRTOptions(max_iterations=40, plans_per_tree=3),
            max_rounds=1,
            backend="serial",
        )


def test_fewer_plans_than_asked_returns_what_was_found(point_robot, caplog):
    plans, trees = rrt_plans(
        point_robot,
        6,
        seed=2,
        options=RRTOptions(max_iterations=40, plans_per_tree=3),
        max_rounds=1,
        backend="serial",
    )
    assert 1 <= len(plans) < 6 and len(trees) == 2
    assert "plans within the budget" in caplog.text


def test_distance_metric_against_a_loop(rng, tol):
    space = BoxSpace(
        low=[0, 0, -math.pi],
        high=[1, 1, math.pi],
        weights=[1, 4, 0.01],
        periodic=[False, False, True],
        goal=[0.5, 0.5, 0],
    )
    xs = rng.uniform(-4, 4, (20, 3))
    x = rng.uniform(-4, 4, 3)
    want = [
        math.sqrt(
            (a[0] - x[0]) ** 2
            + 4 * (a[1] - x[1]) ** 2
            + 0.01 * math.remainder(a[2] - x[2], 2 * math.pi) ** 2
        )
        for a in xs
    ]
    np.testing.assert_allclose(space.distance(xs, x), want, **tol["float64_ref"])
    # towards the goal the heading is ignored
    want_goal = [math.sqrt((a[0] - 0.5) ** 2 + 4 * (a[1] - 0.5) ** 2) for a in xs]
    np.testing.assert_allclose(
        space.distance(xs, space.goal, to_goal=True), want_goal, **tol["float64_ref"]
    )


def test_bad_input_is_named(point_robot):
    with pytest.raises(InvalidInputError, match="weights"):
        BoxSpace(low=[0, 0], high=[1, 1], weights=[0, 0], periodic=[False, False], goal=[0, 0])
    with pytest.raises(InvalidInputError, match="steps_per_extension"):
        BoxSpace(low=[0], high=[1], weights=[1], periodic=[False], goal=[0], steps_per_extension=0)
    with pytest.raises(InvalidInputError, match="n_plans"):
        rrt_plans(point_robot, 0)
    with pytest.raises(InvalidInputError, match="goal_bias"):
        RRTOptions(goal_bias=1.5)

    class NoGoal:
        pass

    with pytest.raises(InvalidInputError, match=r"in_goal|lacks"):
        rrt_plans(NoGoal(), 1)
    with pytest.raises(InvalidInputError, match="planning_space"):
        planning_space(object())


# ---- planning margins: tightened goal, controls off the bounds ------------------------


def test_plans_end_in_tightened_goal_with_margined_controls(near_needle, needle_result):
    """Default options: every plan ends within (1 − 0.5) r_goal of the deformed goal centre,
    and every control keeps 2σ of the actuation noise (0.05, 5°) from the needle's bounds
    (v in [0.1, 0.4], |φ| ≤ φ_max − 10°)."""
    plans, _ = needle_result
    r = near_needle.config.goal_radius
    v_max, phi_max = near_needle.config.v_max, near_needle.config.phi_max
    for plan in plans:
        assert near_needle.goal_distance(plan.states[-1]) <= 0.5 * r
        v, phi = plan.controls[:, 0], plan.controls[:, 1]
        assert np.all((v >= 0.1) & (v <= v_max - 0.1))
        assert np.all(np.abs(phi) <= phi_max - math.radians(10.0) + TOL["float64_abs"]["atol"])


def test_manipulation_sampling_bounds_keep_two_sigma():
    from riskplan.tissue_planning.rrt import sampling_bounds

    sim = ManipulationScenario()
    f = sim.config.df_max
    b = sampling_bounds(sim, RRTOptions())
    # actuation noise 0.1 df_max per increment component: margin 0.2 df_max
    np.testing.assert_allclose(
        b, np.tile([-0.8 * f, 0.8 * f], (sim.control_dim, 1)), **TOL["round_off"]
    )
    assert np.array_equal(sampling_bounds(sim, RRTOptions(control_margin=0.0)), sim.control_bounds)
    with pytest.raises(InvalidInputError, match="control_margin"):
        sampling_bounds(sim, RRTOptions(control_margin=10.0))


def test_point_robot_tight_goal(point_robot):
    """A simulator with a goal_radius and no noise model: tightened goal, full bounds."""
    tree = grow_tree(point_robot, seed=11, options=RRTOptions(plans_per_tree=3, goal_depth=0.75))
    assert tree.plans
    for plan in tree.plans:
        assert point_robot.goal_distance(plan.states[-1]) <= 0.25 * point_robot.goal_radius


def test_zero_margins_reproduce_previous_plans(near_needle, point_robot):
    """goal_depth = control_margin = 0 with goal_entry = goal_steer = False reproduce, bit
    for bit, plans stored from the tree before the margins, the goal-entry ranking and the
    goal steering existed (the point robot's). The needle's stored plans were regenerated
    with these options when its model changed (the tissue now carries the robot, so its
    states differ): for the needle this is a regression check of the zero-margin tree."""
    from pathlib import Path

    ref = np.load(Path(__file__).parent / "data" / "rrt_plans_v1.npz")
    old = RRTOptions(goal_depth=0.0, control_margin=0.0, goal_entry=False, goal_steer=False)
    tree = grow_tree(point_robot, seed=11, options=dataclasses.replace(old, plans_per_tree=3))
    assert len(tree.plans) == 3
    for i, p in enumerate(tree.plans):
        assert p.controls.tobytes() == ref[f"point_{i}_controls"].tobytes()
        assert p.reduced.tobytes() == ref[f"point_{i}_reduced"].tobytes()
    opts = dataclasses.replace(old, plans_per_tree=2, max_iterations=600)
    plans, _ = rrt_plans(near_needle, 2, seed=3, params=SMALL_MESH, options=opts, backend="serial")
    assert len(plans) == 2
    for i, p in enumerate(plans):
        assert p.controls.tobytes() == ref[f"needle_{i}_controls"].tobytes()
        assert p.reduced.tobytes() == ref[f"needle_{i}_reduced"].tobytes()


def test_goal_entry_keeps_an_edge_through_the_goal():
    """Towards the goal point, an edge whose first state is in the goal and whose end lies
    beyond it (farther than its node) ends in the goal with goal_entry, and is dropped
    without it (the end is no closer), so that tree never reaches the goal."""
    robot = PointRobot(goal=(0.2, 0.2), goal_radius=0.05, obstacle=((0.8, 0.8), (0.9, 0.9)))
    robot._bounds = np.array([[0.9, 1.0], [0.9, 1.0]])  # every step moves ~(0.095, 0.095)
    space = BoxSpace(
        low=[0, 0],
        high=[1, 1],
        weights=[1, 1],
        periodic=[False, False],
        goal=robot.goal_center,
        steps_per_extension=3,
    )
    opts = RRTOptions(
        n_controls=2, goal_bias=1.0, max_iterations=20, plans_per_tree=1, goal_depth=0.0
    )
    tree = grow_tree(robot, seed=0, space=space, options=opts)
    assert len(tree.plans) == 1
    plan = tree.plans[0]
    assert plan.n_steps == 1  # the edge ends at its first state, in the goal
    assert robot.in_goal(plan.states[-1])
    x_end = plan.reduced[0] + 3 * (plan.reduced[1] - plan.reduced[0])  # the dropped far end
    assert math.dist(x_end, robot.goal_center) > math.dist(plan.reduced[0], robot.goal_center)
    old = grow_tree(robot, seed=0, space=space, options=dataclasses.replace(opts, goal_entry=False))
    assert old.plans == [] and old.size == 1


def test_goal_steer_control_is_a_candidate_towards_the_goal_only():
    """A space's steer is called in goal-directed extensions only, from the nearest node to
    the goal point, and its control replaces the last candidate: with one candidate per
    extension, every edge of a tree grown towards the goal alone holds a steered control."""
    robot = PointRobot(goal=(0.5, 0.3), goal_radius=0.05, obstacle=((0.8, 0.8), (0.9, 0.9)))
    calls = []

    def steer(x, target, bounds, k):
        calls.append((np.array(x), np.array(target), k))
        return np.clip((target - x) / (0.1 * k), bounds[:, 0], bounds[:, 1])

    space = dataclasses.replace(robot.planning_space(), steps_per_extension=2, steer=steer)
    opts = RRTOptions(n_controls=1, goal_bias=1.0, max_iterations=50, plans_per_tree=1)
    tree = grow_tree(robot, seed=0, space=space, options=opts)
    assert len(tree.plans) == 1
    plan = tree.plans[0]
    # a straight line from (0.1, 0.1) towards (0.5, 0.3): the steered controls, in order
    assert all(np.array_equal(t, robot.goal_center) and k == 2 for _, t, k in calls)
    steered = [np.clip((t - x) / 0.2, -1, 1) for x, t, _ in calls]
    for i, u in enumerate(plan.controls[::2]):
        np.testing.assert_array_equal(u, steered[i])
    assert robot.in_goal(plan.states[-1])
    assert len(calls) == tree.iterations
    # without goal_steer the space's rule is never asked
    calls.clear()
    grow_tree(robot, seed=0, space=space, options=dataclasses.replace(opts, goal_steer=False))
    assert calls == []


def test_steered_control_keeps_the_rate_limit():
    """A steered control obeys the space's max_control_change like the random candidates:
    every control of every edge differs from its parent's by at most the limit."""
    robot = PointRobot(goal=(0.5, 0.3), goal_radius=0.05, obstacle=((0.8, 0.8), (0.9, 0.9)))
    d = np.array([0.1, 0.1])
    space = dataclasses.replace(
        robot.planning_space(),
        max_control_change=d,
        steer=lambda x, t, b, k: np.clip((t - x) / (0.1 * k), b[:, 0], b[:, 1]),
    )
    opts = RRTOptions(n_controls=1, goal_bias=1.0, max_iterations=20, plans_per_tree=1)
    tree = grow_tree(robot, seed=0, space=space, options=opts)
    assert tree.size > 3
    # every edge's control from its end points (x += 0.1 u per step); the root's is the midpoint
    k = space.steps_per_extension
    u = np.zeros_like(tree.nodes)
    for i in range(1, tree.size):
        u[i] = (tree.nodes[i] - tree.nodes[tree.parents[i]]) / (0.1 * k)
    for i in range(1, tree.size):
        step = np.abs(u[i] - u[tree.parents[i]])
        assert np.all(step <= d + TOL["float64_ref"]["atol"]), (i, step)
    # the steering asked for full speed: the limit is what held it back
    assert np.isclose(np.abs(u[1] - u[0]).max(), d.max())


def test_steer_must_be_callable():
    with pytest.raises(InvalidInputError, match="steer"):
        BoxSpace(
            low=[0, 0], high=[1, 1], weights=[1, 1], periodic=[False, False], goal=[1, 1], steer=3
        )


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("goal_steer", 0),
        ("goal_depth", 1.0),
        ("goal_depth", -0.1),
        ("control_margin", -1.0),
        ("goal_entry", 1),
        ("goal_entry", "yes"),
    ],
)
def test_margin_options_validated(field, value):
    with pytest.raises(InvalidInputError, match=field):
        RRTOptions(**{field: value})


def test_goal_connect_extends_until_the_goal_in_one_iteration():
    """goal_connect: after a goal-directed edge, steered edges follow until the goal (one
    iteration reaches a goal 6 edges away); the plan replays, is collision-free and ends
    at its first state in the goal; without it the same tree needs one iteration per edge."""
    robot = PointRobot(goal=(0.7, 0.5), goal_radius=0.05, obstacle=((0.8, 0.0), (0.9, 0.1)))

    def steer(x, target, bounds, k):
        return np.clip((target - x) / (0.1 * k), bounds[:, 0], bounds[:, 1])

    space = dataclasses.replace(robot.planning_space(), steps_per_extension=1, steer=steer)
    opts = RRTOptions(n_controls=1, goal_bias=1.0, max_iterations=40, plans_per_tree=1)
    connected = grow_tree(
        robot, seed=0, space=space, options=dataclasses.replace(opts, goal_connect=20)
    )
    plain = grow_tree(robot, seed=0, space=space, options=opts)
    assert len(connected.plans) == 1 and connected.iterations == 1
    assert connected.size == connected.plans[0].n_steps + 1  # one node per steered edge
    assert plain.plans == [] or plain.iterations > 1
    plan = connected.plans[0]
    replay = NominalPlan.from_rollout(robot, robot.initial_state(), plan.controls)
    assert plan.reduced.tobytes() == replay.reduced.tobytes()
    assert not any(robot.in_collision(s) for s in plan.states)
    assert _in_tight_goal(robot, plan.states[-1])
    assert not any(_in_tight_goal(robot, s) for s in plan.states[:-1])


def test_goal_connect_stops_when_blocked():
    """A connection that would cross an obstacle stops before it: no node in it."""
    robot = PointRobot(goal=(0.9, 0.1), goal_radius=0.05, obstacle=((0.4, 0.0), (0.5, 0.2)))

    def steer(x, target, bounds, k):
        return np.clip((target - x) / (0.1 * k), bounds[:, 0], bounds[:, 1])

    space = dataclasses.replace(robot.planning_space(), steps_per_extension=1, steer=steer)
    opts = RRTOptions(n_controls=1, goal_bias=1.0, max_iterations=5, plans_per_tree=1)
    tree = grow_tree(robot, seed=0, space=space, options=dataclasses.replace(opts, goal_connect=20))
    assert tree.plans == [] and tree.size > 1
    assert np.all(tree.nodes[:, 0] < 0.4)  # every node before the obstacle


def test_goal_connect_validates():
    with pytest.raises(InvalidInputError, match="goal_connect"):
        RRTOptions(goal_connect=-1)


def _steered_point_robot(**connect):
    """A point robot with a straight-line steering rule: the steered control from a node
    towards the goal point is the same every time it is asked."""
    robot = PointRobot(goal=(0.7, 0.5), goal_radius=0.05, obstacle=((0.8, 0.0), (0.9, 0.1)))

    def steer(x, target, bounds, k):
        return np.clip((target - x) / (0.1 * k), bounds[:, 0], bounds[:, 1])

    space = dataclasses.replace(robot.planning_space(), steps_per_extension=1, steer=steer)
    return robot, space


def _children_states_distinct(tree) -> bool:
    kids: dict[int, list[bytes]] = {}
    for i in range(1, tree.size):
        kids.setdefault(int(tree.parents[i]), []).append(tree.nodes[i].tobytes())
    return all(len(set(v)) == len(v) for v in kids.values())


def test_a_node_makes_one_steered_child_so_the_plans_of_a_tree_are_distinct():
    """The steering rule is deterministic: a node picked for the goal again (after the
    goal's parent is exhausted) would get a second child with the first one's state, and
    the goal connection would repeat the path to the goal. Each node's steered control
    makes at most one child, so no two children of a node share a state, and the tree's
    plans are distinct."""
    robot, space = _steered_point_robot()
    opts = RRTOptions(
        n_controls=2, goal_bias=1.0, max_iterations=60, plans_per_tree=4, goal_connect=20
    )
    for seed in range(3):
        tree = grow_tree(robot, seed=seed, space=space, options=opts)
        assert len(tree.plans) >= 2
        assert _children_states_distinct(tree)
        keys = [p.controls.tobytes() for p in tree.plans]
        assert len(set(keys)) == len(keys)
        for plan in tree.plans:
            replay = NominalPlan.from_rollout(robot, robot.initial_state(), plan.controls)
            assert plan.reduced.tobytes() == replay.reduced.tobytes()
        again = grow_tree(robot, seed=seed, space=space, options=opts)
        assert again.nodes.tobytes() == tree.nodes.tobytes()


def test_rrt_plans_keeps_a_path_repeated_by_several_trees_once():
    """Every tree starts at the same root, and its first goal-directed step there (steered
    and connected) reaches the goal on the same straight path: the trees' plans repeat it,
    rrt_plans keeps it once and returns distinct plans, the same for the same seed."""
    robot, space = _steered_point_robot()
    opts = RRTOptions(
        n_controls=2, goal_bias=1.0, max_iterations=60, plans_per_tree=2, goal_connect=20
    )
    plans, trees = rrt_plans(robot, 3, seed=5, space=space, options=opts, backend="serial")
    grown = [p.controls.tobytes() for t in trees for p in t.plans]
    assert len(set(grown)) < len(grown)  # the trees did repeat a path
    keys = [p.controls.tobytes() for p in plans]
    assert len(plans) == 3 and len(set(keys)) == 3
    assert set(keys) == set(grown)
    again, _ = rrt_plans(robot, 3, seed=5, space=space, options=opts, backend="serial")
    assert [p.controls.tobytes() for p in again] == keys
