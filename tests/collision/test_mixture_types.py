"""Every collision entry point gives the same numbers for the NumPy mixture core and for the
torch GaussianMixture it converts from (float64: bit for bit, the same arrays go in)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from riskplan.collision import (
    component_bounds,
    monte_carlo_probability,
    monte_carlo_trajectory,
    probability_of_collision,
    trajectory_bound,
)
from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import NumpyMixture
from riskplan.kinematics import GaussianMixture
from riskplan.kinematics.robot_mixture import (
    arc_backbone,
    backbone_mixture,
    backbone_numpy_mixture,
)
from tests.collision.conftest import random_upper


def _pair(rng, batch, K, d=3):
    w = rng.dirichlet(np.ones(K), size=batch)
    m = rng.normal(size=(*batch, K, d)) * 0.5
    u = np.stack([random_upper(rng, d) for _ in range(int(np.prod(batch)) * K)]).reshape(
        *batch, K, d, d
    )
    return NumpyMixture(w, m, u), GaussianMixture(w, m, u)


@pytest.mark.parametrize("method", ["bound", "union", "monte_carlo", "monte_carlo_union"])
def test_probability_same_for_both_types(rng, boxes_env, method):
    nm, tm = _pair(rng, (2, 3), 4)
    a = probability_of_collision(nm, boxes_env, method, n_samples=2000, seed=3)
    b = probability_of_collision(tm, boxes_env, method, n_samples=2000, seed=3)
    assert a.shape == (2, 3)
    np.testing.assert_array_equal(a, b)


def test_trajectory_and_components_same_for_both_types(rng, boxes_env):
    nm, tm = _pair(rng, (2, 5), 3)
    np.testing.assert_array_equal(trajectory_bound(nm, boxes_env), trajectory_bound(tm, boxes_env))
    for x, y in zip(component_bounds(nm, boxes_env), component_bounds(tm, boxes_env)):
        np.testing.assert_array_equal(x, y)
    a = monte_carlo_trajectory(nm, boxes_env, 500, segments=True, seed=1)
    b = monte_carlo_trajectory(tm, boxes_env, 500, segments=True, seed=1)
    np.testing.assert_array_equal(a.hits, b.hits)
    c = monte_carlo_probability(nm, boxes_env, 500, seed=2, interval="clopper-pearson")
    d = monte_carlo_probability(tm, boxes_env, 500, seed=2, interval="clopper-pearson")
    np.testing.assert_array_equal(c.low, d.low)


def test_float32_torch_mixture_is_its_float64_cast(rng, boxes_env):
    _, tm = _pair(rng, (4,), 2)
    t32 = tm.to(torch.float32)
    cast = t32.to(torch.float64)
    np.testing.assert_array_equal(
        probability_of_collision(t32, boxes_env), probability_of_collision(cast, boxes_env)
    )


def test_backbone_builders_agree():
    P = arc_backbone(np.array([0.0, 4.0, 9.0]), np.array([0.0, 1.0, 2.0]))
    nm, tm = backbone_numpy_mixture(P, 5), backbone_mixture(P, 5)
    assert isinstance(nm, NumpyMixture) and isinstance(tm, GaussianMixture)
    for name, arr in tm.numpy().items():
        np.testing.assert_array_equal(getattr(nm, name), arr)


def test_numpy_mixture_checked_at_the_boundary(rng, boxes_env):
    nm, _ = _pair(rng, (2,), 2, d=2)
    with pytest.raises(InvalidInputError, match="dimension"):
        probability_of_collision(nm, boxes_env)
    bad = NumpyMixture([0.5, 0.6], np.zeros((2, 3)), np.stack([np.eye(3)] * 2), validate=False)
    with pytest.raises(InvalidInputError, match="sum to 1"):
        probability_of_collision(bad, boxes_env)
    # validate=False trusts the caller (the planners' hot path)
    ok = NumpyMixture([0.5, 0.5], np.zeros((2, 3)), np.stack([np.eye(3)] * 2))
    assert np.isfinite(probability_of_collision(ok, boxes_env, validate=False))
