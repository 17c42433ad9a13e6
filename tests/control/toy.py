"""A linear toy simulator following the Simulator protocol (the oracle of the control tests).

    x_{t+1} = A x_t + B u_t' + c (force_scale − 1),    u_t' = clip(u_t + w_t)   (actuation noise)
    z = H x + n,  n ~ N(0, N)

With ``force_scale ~ U[0, 2]`` the parameter term is zero-mean with covariance ``c cᵀ / 3``.
Obstacles and goal are static polygons over ``x[:2]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan.scenarios.base import (
    SimParams,
    apply_actuation_noise,
    check_control,
    frozen_array,
    gaussian_noise,
)
from riskplan.scenarios.uncertainty import InteractionForceUncertainty


@dataclass(frozen=True, eq=False)
class ToyState:
    t: int
    x: np.ndarray
    n_elements: int = 175

    def __post_init__(self):
        object.__setattr__(self, "x", frozen_array(self.x))

    def identical(self, other) -> bool:
        return self.t == other.t and self.x.tobytes() == other.x.tobytes()


def square(cx, cy, h):
    return np.array([[cx - h, cy - h], [cx + h, cy - h], [cx + h, cy + h], [cx - h, cy + h]])


class LinearToy:
    def __init__(
        self,
        A,
        B,
        c=None,
        H=None,
        sensing_std=0.05,
        u_max=10.0,
        distribution=None,
        x0=None,
        obstacles=(),
        goal=None,
        nan_at=None,
    ):
        self.A_true = np.asarray(A, float)
        self.B_true = np.asarray(B, float)
        self.state_dim, self.control_dim = self.B_true.shape
        self.c = np.zeros(self.state_dim) if c is None else np.asarray(c, float)
        self.observation_matrix = np.eye(self.state_dim)[:2] if H is None else np.asarray(H, float)
        self.obs_dim = self.observation_matrix.shape[0]
        self.sensing_cov = sensing_std**2 * np.eye(self.obs_dim)
        self._bounds = np.tile([[-u_max, u_max]], (self.control_dim, 1)).astype(float)
        self.distribution = distribution
        self.x0 = np.zeros(self.state_dim) if x0 is None else np.asarray(x0, float)
        self._obstacles = [np.asarray(o, float) for o in obstacles]
        self._goal = goal
        self.nan_at = nan_at

    @property
    def control_bounds(self):
        return self._bounds

    @property
    def nominal_params(self):
        return SimParams()

    def initial_state(self, params=None):
        return ToyState(0, self.x0)

    def step(self, state, control, params=None):
        params = params or self.nominal_params
        u = check_control(control, self._bounds)
        u = apply_actuation_noise(u, params, state.t, self._bounds)
        x = self.A_true @ state.x + self.B_true @ u + self.c * (params.force_scale - 1.0)
        if self.nan_at is not None and state.t + 1 == self.nan_at:
            x = x * np.nan
        return ToyState(state.t + 1, x)

    def reduced(self, state):
        return np.array(state.x)

    def observe(self, x, noise=None, rng=None):
        return self.observation_matrix @ np.asarray(x) + gaussian_noise(
            self.sensing_cov, noise, rng, self.obs_dim
        )

    def sample_params(self, seed=None):
        return self.distribution.sample(seed) if self.distribution else self.nominal_params

    def obstacles(self, state=None):
        return list(self._obstacles)

    def goal(self, state=None):
        return self._goal

    def in_collision(self, state):
        from riskplan.geometry2d import points_in_polygon

        return any(points_in_polygon(state.x[None, :2], o)[0] for o in self._obstacles)

    def in_goal(self, state):
        from riskplan.geometry2d import points_in_polygon

        return bool(points_in_polygon(state.x[None, :2], self._goal)[0])


def toy_system(rng, p=3, q=3, scale=0.3):
    A = np.eye(p) + scale * rng.standard_normal((p, p))
    B = rng.standard_normal((p, q))
    c = rng.standard_normal(p)
    return A, B, c


FORCE = InteractionForceUncertainty()
