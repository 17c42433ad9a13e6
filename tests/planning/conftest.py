"""Planning fixtures: an analytic two-tendon "kinematic model" and a small scene.

The model is a closed form (no training), so tests are fast and the oracle is exact: two
Gaussian components whose means move linearly with the displacements (a base-side component
and a tip component), isotropic standard deviation ``SIGMA``. The tip sweeps the square
``[-0.1, 0.1]^2`` at height ``HEIGHT`` as ``d`` sweeps the limits.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from riskplan import geometry2d as geo
from riskplan.kinematics import GaussianMixture
from riskplan.scenarios.base import SimParams, check_control, frozen_array
from riskplan.scenarios.needle import NeedleConfig, NeedleScenario

LIMITS = np.array([[-0.01, 0.04], [-0.01, 0.04]])
SIGMA = 0.004
HEIGHT = 0.1
GAIN = 4.0


class AnalyticModel:
    """``predict(d (..., 2)) -> GaussianMixture`` with means ``s_k (GAIN (d - 0.015), HEIGHT)``."""

    limits = LIMITS
    n_tendons = 2

    def __init__(self, gain: float = GAIN):
        self.gain = gain

    def tip(self, d):
        d = np.asarray(d, dtype=np.float64)
        xy = self.gain * (d - 0.015)
        return np.concatenate([xy, np.full(d.shape[:-1] + (1,), HEIGHT)], axis=-1)

    def predict(self, d):
        d = np.asarray(d, dtype=np.float64)
        tip = self.tip(d)
        means = np.stack([0.5 * tip, tip], axis=-2)
        shape = d.shape[:-1]
        w = np.broadcast_to([0.4, 0.6], shape + (2,)).copy()
        u = np.broadcast_to(np.eye(3) / SIGMA, shape + (2, 3, 3)).copy()
        return GaussianMixture(
            torch.from_numpy(w), torch.from_numpy(means), torch.from_numpy(u), validate=False
        )


def box_env(center, half):
    import trimesh

    from riskplan.collision import Environment

    b = trimesh.creation.box(extents=2 * np.asarray(half, dtype=float))
    b.apply_translation(center)
    return Environment.from_meshes([b], names=["box"])


@pytest.fixture(scope="session")
def model():
    return AnalyticModel()


@pytest.fixture(scope="session")
def scene():
    """A box in the middle of the tip's square: paths from one side to the other go around it."""
    return box_env([0.0, 0.0, HEIGHT], [0.03, 0.03, 0.03])


@pytest.fixture(scope="session")
def wall():
    """A wall across the tip's square (x in [-0.01, 0.01]): no path from x < 0 to x > 0."""
    return box_env([0.0, 0.0, HEIGHT], [0.01, 0.2, 0.05])


# start / goal on opposite corners of the square (tips at (-0.06, -0.06) and (0.06, 0.06))
START = np.array([0.0, 0.0])
GOAL = np.array([0.03, 0.03])


# ---- tissue planner fixtures: small, fast problems (a nearby goal, a coarse mesh) ----

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
    from riskplan.tissue_planning.rrt import RRTOptions, rrt_plans

    options = RRTOptions(plans_per_tree=2, max_iterations=1200)
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
    a square obstacle, a disk goal, and its own ``planning_space()`` (the planning seam,
    :class:`riskplan.scenarios.space.PlanningScenario`)."""

    control_dim = 2
    state_dim = 2
    obs_dim = 2

    def __init__(self, goal=(0.8, 0.8), goal_radius=0.08, obstacle=((0.35, 0.35), (0.6, 0.6))):
        self._bounds = np.array([[-1.0, 1.0], [-1.0, 1.0]])
        self.goal_center = np.asarray(goal, float)
        self.goal_radius = goal_radius
        self.obstacle = geo.rectangle_polygon(*obstacle)

    def planning_space(self):
        from riskplan.scenarios.space import BoxSpace

        return BoxSpace(
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
