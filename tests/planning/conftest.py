"""Planning fixtures: an analytic two-tendon "kinematic model" and a small scene.

The model is a closed form (no training), so tests are fast and the oracle is exact: two
Gaussian components whose means move linearly with the displacements (a base-side component
and a tip component), isotropic standard deviation ``SIGMA``. The tip sweeps the square
``[-0.1, 0.1]^2`` at height ``HEIGHT`` as ``d`` sweeps the limits.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from riskplan.kinematics import GaussianMixture

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
        return GaussianMixture(torch.from_numpy(w), torch.from_numpy(means), torch.from_numpy(u), validate=False)


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
