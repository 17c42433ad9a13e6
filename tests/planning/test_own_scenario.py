"""The planning seam from a user's side: a scenario written here, outside the package, is
planned for by the simulator RRT, linearised, executed under LQG and scored by LQG-MP
without any change to ``riskplan.planning`` or ``riskplan.control``.

The scenario is a point robot in the unit square, ``x_{t+1} = x_t + τ clip(u_t + w_t)``
(``w_t ~ N(0, σ_w² I)``, the actuation noise), observed as ``z = x + n``, with one square
obstacle and a disk goal. Being linear, its executions *are* the linear-Gaussian model
LQG-MP propagates, which gives the oracles: the linearisation is exact (A = I, B = τ I;
M = τ² σ_w² I within the sampling error of its draws) and LQG-MP's ``"sampling"``
probability agrees with closed-loop Monte Carlo executions within their binomial error.
"""

from __future__ import annotations

import ast
import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy import stats

from riskplan import geometry2d as geo
from riskplan.control import execute, linearize, lqg_controller, lqgmp, monte_carlo_success
from riskplan.scenarios.base import (
    SimParams,
    Simulator,
    apply_actuation_noise,
    check_control,
    frozen_array,
    gaussian_noise,
)
from riskplan.scenarios.space import BoxSpace, PlanningScenario, PlanningSpace
from riskplan.scenarios.uncertainty import ActuationNoise
from riskplan.tissue_planning.rrt import RRTOptions, rrt_plans
from tests.conftest import TOL

TAU = 0.1
SIGMA_W = 0.1  # actuation noise per control component (the bounds are ±1)
SENSING = 0.01


@dataclasses.dataclass(frozen=True, eq=False)
class DotState:
    t: int
    x: np.ndarray
    n_elements: int = 175  # the SimParams mesh size the control stage compares against

    def __post_init__(self):
        object.__setattr__(self, "x", frozen_array(self.x))

    def identical(self, other) -> bool:
        return self.t == other.t and self.x.tobytes() == other.x.tobytes()


class Dot:
    """A point robot: the whole scenario a user writes to plan with riskplan."""

    control_dim = 2
    state_dim = 2
    obs_dim = 2
    goal_radius = 0.08

    def __init__(self):
        self.control_bounds = np.array([[-1.0, 1.0], [-1.0, 1.0]])
        self.observation_matrix = np.eye(2)
        self.sensing_cov = SENSING**2 * np.eye(2)
        self.state_scale = np.array([0.04, 0.04])
        self.distribution = ActuationNoise(cov=((SIGMA_W**2, 0.0), (0.0, SIGMA_W**2)))
        self.goal_center = np.array([0.8, 0.5])
        self._obstacle = geo.rectangle_polygon((0.4, 0.3), (0.55, 0.7))
        self._goal = geo.circle_polygon(self.goal_center, self.goal_radius, 48)

    # the Simulator protocol
    @property
    def nominal_params(self):
        return SimParams()

    def initial_state(self, params=None):
        return DotState(0, [0.15, 0.5])

    def step(self, state, control, params=None):
        params = params or self.nominal_params
        u = check_control(control, self.control_bounds)
        u = apply_actuation_noise(u, params, state.t, self.control_bounds)
        return DotState(state.t + 1, state.x + TAU * u)

    def reduced(self, state):
        return np.array(state.x)

    def observe(self, x, noise=None, rng=None):
        return np.asarray(x, dtype=np.float64) + gaussian_noise(self.sensing_cov, noise, rng, 2)

    def sample_params(self, seed=None):
        return self.distribution.sample(seed)

    def actuation_cov(self):
        return self.distribution.cov

    # what planning, execution and LQG-MP ask for
    def planning_space(self):
        return BoxSpace(
            low=[0, 0], high=[1, 1], weights=[1, 1], periodic=[False, False], goal=self.goal_center
        )

    def obstacles(self, state=None):
        return [self._obstacle]

    def goal(self, state=None):
        return self._goal

    def in_collision(self, state):
        return bool(geo.points_in_polygon(state.x[None], self._obstacle)[0])

    def in_goal(self, state):
        return bool(geo.points_in_polygon(state.x[None], self._goal)[0])

    def goal_distance(self, state):
        return float(math.dist(state.x, self.goal_center))


def test_own_scenario_meets_the_protocols():
    sim = Dot()
    assert isinstance(sim, Simulator)
    assert isinstance(sim, PlanningScenario)
    assert isinstance(sim.planning_space(), PlanningSpace)


def test_own_scenario_plans_executes_and_scores():
    sim = Dot()
    plans, _ = rrt_plans(
        sim, 2, seed=5, options=RRTOptions(plans_per_tree=2, max_iterations=3000), backend="serial"
    )
    plan = plans[0]
    # the plan goes round the obstacle and ends in the tightened goal
    assert not any(sim.in_collision(s) for s in plan.states)
    assert sim.goal_distance(plan.states[-1]) <= 0.5 * sim.goal_radius
    T = plan.n_steps

    lin = linearize(sim, plan, n_samples=400, seed=1)
    eye = np.broadcast_to(np.eye(2), (T, 2, 2))
    np.testing.assert_allclose(lin.A, eye, **TOL["float64_accumulated"])
    np.testing.assert_allclose(lin.B, TAU * eye, **TOL["float64_accumulated"])
    # M_t: the second moment of 400 draws of τ w (w ~ N(0, σ_w² I), clipped where a control
    # lies within reach of a bound): each diagonal entry is σ² χ²_400 / 400
    m_true = (TAU * SIGMA_W) ** 2
    lo, hi = stats.chi2.ppf([1e-4, 1 - 1e-4], 400) / 400
    diag = np.diagonal(lin.M, axis1=1, axis2=2)
    assert np.all(diag <= hi * m_true) and np.all(diag >= 0.5 * lo * m_true), diag

    # the exact model of this system, to compare LQG-MP with executions of the same model
    exact = dataclasses.replace(
        lin, A=eye, B=TAU * eye, M=np.broadcast_to(m_true * np.eye(2), lin.M.shape)
    )
    ctrl = lqg_controller(exact)
    run = execute(sim, plan, ctrl, sim.sample_params(7), seed=8)
    assert run.outcome in ("success", "collision", "missed_goal")
    n_mc, n_s = 1000, 20_000
    mc = monte_carlo_success(sim, plan, ctrl, sim.distribution, n=n_mc, seed=3)
    smp = lqgmp(sim, plan, ctrl, method="sampling", n_goal_samples=n_s, seed=0)
    p = mc.probability
    se = math.sqrt(max(p * (1 - p), 1.0 / n_mc) * (1 / n_mc + 1 / n_s))
    assert 0.1 < p < 0.95, p  # the obstacle matters
    assert abs(smp.p_success - p) < 4.5 * se, (smp.p_success, p, se)


def test_planning_and_control_name_no_scenario():
    """The seam holds by construction: nothing in tissue_planning/ (the RRT, the selection) or control/ imports a
    scenario module (only the protocols in scenarios.base and scenarios.space)."""
    root = Path(__file__).resolve().parents[2] / "src" / "riskplan"
    allowed = {"riskplan.scenarios.base", "riskplan.scenarios.space"}
    paths = [
        *(root / "control").glob("*.py"),
        root / "tissue_planning" / "rrt.py",
        root / "tissue_planning" / "select.py",
    ]
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                "riskplan.scenarios"
            ):
                assert node.module in allowed, f"{path.name} imports {node.module}"
