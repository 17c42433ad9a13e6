"""The default chest goal (planning/chest.py): the recess rule on the robot model, and start
and goal free on the simulated robot (issue 18, item 10)."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.errors import InvalidInputError, PlanningError
from riskplan.planning.chest import (
    DEFAULT_GOAL,
    DEFAULT_GOAL_TIP,
    RECESS_DEPTH,
    RECESS_FLOOR,
    body_clearance,
    recess_goal,
)
from riskplan.planning.validate import execute_on_robot
from tests.conftest import TOL


@pytest.fixture(scope="module")
def scene():
    from riskplan.planning.chest_scene import build_chest
    from riskplan.robots import load_robot

    return load_robot("paper"), build_chest(0).base_environment


@pytest.fixture(scope="module")
def found(scene):
    robot, env = scene
    return recess_goal(robot, env)


def test_default_goal_is_the_rule(found, scene):
    """The shipped constants are what the documented rule finds (rounded to 0.01 mm)."""
    np.testing.assert_allclose(found.goal, DEFAULT_GOAL, **TOL["quoted_10um"])
    robot, env = scene
    tip, c = body_clearance(robot, np.asarray(DEFAULT_GOAL)[None], env)
    np.testing.assert_allclose(tip[0], DEFAULT_GOAL_TIP, **TOL["quoted_10um"])
    # in the recess: caudal, posterior, within RECESS_DEPTH of the diaphragm; body clear
    df = env.subset([RECESS_FLOOR]).signed_distance(tip)[0]
    assert tip[0, 0] < 0 and tip[0, 1] < 0 and 0 < df <= RECESS_DEPTH
    assert c[0] > 0 and found.clearance >= c[0] - TOL["quoted_10um"]["atol"]
    assert found.in_recess > 0 and found.evaluated > found.in_recess


def test_rule_maximises_the_clearance(found, scene):
    """No configuration of an independent draw in the recess has more clearance than the rule's."""
    robot, env = scene
    lim = np.asarray(robot.displacement_limits)
    q = np.random.default_rng(123).uniform(lim[:, 0], lim[:, 1], size=(1024, len(lim)))
    q = q[(robot.tensions_for_displacements(q) <= robot.tension_limits).all(-1)]
    tip, c = body_clearance(robot, q, env)
    df = env.subset([RECESS_FLOOR]).signed_distance(tip)
    inside = (tip[:, 0] < 0) & (tip[:, 1] < 0) & (df > 0) & (df <= RECESS_DEPTH)
    assert inside.sum() > 10
    assert c[inside].max() <= found.clearance


@pytest.mark.parametrize("name, config", [("start", (0.0, 0.0, 0.0, 0.0)), ("goal", DEFAULT_GOAL)])
def test_start_and_goal_are_free_on_the_robot(scene, name, config):
    """<= 5 % of 200 executions collide with the body the MDN learned (backbone and disks)."""
    robot, env = scene
    r = execute_on_robot(
        robot, np.asarray(config)[None], env, 200, 0, body="disks", backend="serial"
    )
    assert r.trajectory.hits <= 10, (name, r.trajectory.hits)


def test_counterfactual_a_tip_on_the_floor_collides(scene):
    """The rule's reason: a configuration whose tip is within the disk radius of the diaphragm
    (the tip of the earlier default target) collides on the robot whatever its clearance elsewhere."""
    robot, env = scene
    lim = np.asarray(robot.displacement_limits)
    q = np.random.default_rng(5).uniform(lim[:, 0], lim[:, 1], size=(1024, len(lim)))
    tip, c = body_clearance(robot, q, env)
    df = env.subset([RECESS_FLOOR]).signed_distance(tip)
    near = (df > 0) & (df < 0.005)
    assert near.sum() > 0 and (c[near] < 0).all()


def test_recess_goal_errors(scene):
    robot, env = scene
    with pytest.raises(InvalidInputError, match="floor"):
        recess_goal(robot, env, floor="liver")
    with pytest.raises(InvalidInputError, match="depth"):
        recess_goal(robot, env, depth=-0.01)
    with pytest.raises(PlanningError, match="no configuration"):
        recess_goal(robot, env, depth=1e-6, n_samples=64)
