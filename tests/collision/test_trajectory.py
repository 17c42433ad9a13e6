"""Trajectory probability (eq. 10) and its Monte Carlo reference."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.collision import (
    monte_carlo_trajectory,
    probability_of_collision,
    trajectory_bound,
    trajectory_probability,
)
from riskplan.errors import InvalidInputError
from riskplan.kinematics import GaussianMixture
from tests.collision.conftest import random_upper
from tests.conftest import TOL


def test_eq10_against_product(rng):
    p = rng.uniform(0, 0.3, size=(4, 7))
    ref = 1 - np.prod(1 - p, axis=-1)
    np.testing.assert_allclose(trajectory_probability(p), ref, **TOL["float64_exact"])
    np.testing.assert_allclose(
        trajectory_probability(p, combine="union"), np.minimum(1, p.sum(-1)), **TOL["float64_exact"]
    )
    assert np.all(
        trajectory_probability(p, combine="union")
        >= trajectory_probability(p) - TOL["round_off"]["atol"]
    )
    np.testing.assert_allclose(trajectory_probability(p.T, axis=0), ref, **TOL["float64_exact"])
    # tiny probabilities keep their precision
    np.testing.assert_allclose(
        trajectory_probability(np.full(10, 1e-18)), 1e-17, **TOL["float64_exact_rel"]
    )
    assert trajectory_probability(np.array([0.2, 1.0])) == 1.0


def test_trajectory_bound_covers_monte_carlo(rng, boxes_env):
    T, K = 6, 3
    t = np.linspace(0, 1, T)
    means = np.stack(
        [np.stack([[-1.0 + 2.0 * ti, 0.0 + 0.2 * k, 0.0] for k in range(K)]) for ti in t]
    )  # passes between boxes
    U = np.stack([np.stack([random_upper(rng, 3, scale=0.6) for _ in range(K)]) for _ in range(T)])
    gm = GaussianMixture(np.full((T, K), 1 / K), means, U)
    p_t = probability_of_collision(gm, boxes_env)
    bound = trajectory_bound(gm, boxes_env)
    np.testing.assert_allclose(bound, trajectory_probability(p_t), **TOL["float64_exact"])
    mc = monte_carlo_trajectory(gm, boxes_env, 4000, seed=5, confidence=0.999)
    assert mc.probability.shape == ()
    assert bound >= mc.low - TOL["float64_abs"]["atol"]
    # checking segments between consecutive draws can only add collisions
    mcs = monte_carlo_trajectory(gm, boxes_env, 4000, seed=5, segments=True)
    assert mcs.hits >= mc.hits
    # batch of trajectories equals loop
    gm2 = GaussianMixture(
        np.stack([gm.weights] * 2),
        np.stack([gm.means, gm.means + 0.3]),
        np.stack([gm.precision_cholesky] * 2),
    )
    b2 = trajectory_bound(gm2, boxes_env)
    np.testing.assert_allclose(
        b2,
        [trajectory_bound(gm2[0], boxes_env), trajectory_bound(gm2[1], boxes_env)],
        **TOL["float64_exact"],
    )


def test_bad_inputs():
    with pytest.raises(InvalidInputError, match="in \\[0, 1\\]"):
        trajectory_probability(np.array([0.1, 1.2]))
    with pytest.raises(InvalidInputError, match="in \\[0, 1\\]"):
        trajectory_probability(np.array([0.1, np.nan]))
    with pytest.raises(InvalidInputError, match="combine"):
        trajectory_probability(np.array([0.1]), combine="max")
