"""Fixtures of the tissue-planner tests: small, fast problems (a nearby goal, a coarse mesh)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskplan.scenarios import _geometry as geo
from riskplan.scenarios.base import SimParams, check_control, frozen_array
from riskplan.scenarios.needle import NeedleConfig, NeedleScenario

#: Coarse planning mesh of the tests (the scenarios plan on 175 elements).
SMALL_MESH = SimParams(n_elements=60)


@pytest.fixture(scope="session")
def near_needle():
    """The needle scenario with the goal 0.45 ahead of the start and one obstacle near the way."""
    cfg = NeedleConfig(
        goal_center=(0.5, 0.55),
        goal_radius=0.08,
        obstacles=(geo.rectangle_polygon((0.25, 0.25), (0.32, 0.40)),),
    )
    return NeedleScenario(cfg)


@pytest.fixture(scope="session")
def needle_result(near_needle):
    """Four candidate plans (two trees) on the coarse mesh, and the trees."""
    from riskplan.planning.rrt import RRTOptions, rrt_plans

    options = RRTOptions(plans_per_tree=2, max_iterations=600)
    return rrt_plans(near_needle, 4, seed=3, params=SMALL_MESH, options=options, backend="serial")


class PointState:
    """State of :class:`PointRobot`: step index and position."""

    def __init__(self, t, x):
        self.t = int(t)
        self.x = frozen_array(x)

    def identical(self, other) -> bool:
        return self.t == other.t and self.x.tobytes() == other.x.tobytes()


class PointRobot:
    """A user simulator: a point in the unit square moved by ``x += 0.1 u``, ``|u_i| ≤ 1``,
    a square obstacle, a disk goal, and its own ``planning_space`` (the protocol extension)."""

    control_dim = 2
    state_dim = 2
    obs_dim = 2

    def __init__(self, goal=(0.8, 0.8), goal_radius=0.08, obstacle=((0.35, 0.35), (0.6, 0.6))):
        from riskplan.planning.rrt import PlanningSpace

        self._bounds = np.array([[-1.0, 1.0], [-1.0, 1.0]])
        self.goal_center = np.asarray(goal, float)
        self.goal_radius = goal_radius
        self.obstacle = geo.rectangle_polygon(*obstacle)
        self.planning_space = PlanningSpace(
            low=[0, 0], high=[1, 1], weights=[1, 1], periodic=[False, False], goal=self.goal_center
        )

    control_bounds = property(lambda self: self._bounds)
    nominal_params = property(lambda self: SimParams())

    def initial_state(self, params=None):
        return PointState(0, [0.1, 0.1])

    def step(self, state, control, params=None):
        u = check_control(control, self._bounds)
        return PointState(state.t + 1, state.x + 0.1 * u)

    def reduced(self, state):
        return np.array(state.x)

    def observe(self, x, noise=None, rng=None):
        return np.asarray(x, float)

    def sample_params(self, seed=None):
        return self.nominal_params

    def in_collision(self, state):
        return bool(geo.points_in_polygon(state.x[None], self.obstacle)[0])

    def goal_distance(self, state):
        return float(math.dist(state.x, self.goal_center))

    def in_goal(self, state):
        return self.goal_distance(state) <= self.goal_radius


@pytest.fixture
def point_robot():
    return PointRobot()
