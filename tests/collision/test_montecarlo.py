"""Monte Carlo reference: intervals, seeding, path checks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binomtest

from riskplan.collision import (
    Environment,
    binomial_interval,
    monte_carlo_probability,
    paths_collide,
)
from riskplan.errors import InvalidInputError
from riskplan.kinematics import GaussianMixture
from tests.collision.conftest import box_mesh
from tests.conftest import TOL


@pytest.mark.parametrize(
    "method, scipy_method", [("wilson", "wilson"), ("clopper-pearson", "exact")]
)
def test_intervals_match_scipy(method, scipy_method):
    for k, n in ((0, 50), (3, 50), (25, 50), (50, 50), (137, 10000)):
        lo, hi = binomial_interval(k, n, 0.95, method)
        ci = binomtest(k, n).proportion_ci(0.95, method=scipy_method)
        np.testing.assert_allclose([lo, hi], [ci.low, ci.high], **TOL["scipy_reference"])


def test_vectorised_wilson_matches_scipy_per_entry():
    """The closed form on a whole array of hit counts against scipy's binomtest, entry by
    entry (the maintained implementation is the oracle of the vectorised one)."""
    n = 200
    hits = np.arange(0, n + 1, 7)
    for conf in (0.9, 0.95, 0.99):
        lo, hi = binomial_interval(hits, n, conf, "wilson")
        want = [binomtest(int(k), n).proportion_ci(conf, method="wilson") for k in hits]
        np.testing.assert_allclose(lo, [c.low for c in want], **TOL["scipy_reference"])
        np.testing.assert_allclose(hi, [c.high for c in want], **TOL["scipy_reference"])


def test_seeded_and_consistent(boxes_env):
    gm = GaussianMixture.from_covariances(
        np.array([0.5, 0.5]),
        np.array([[0.5, 0, 0], [0.0, 1.0, 0]]),
        np.stack([np.eye(3) * 0.3] * 2),
    )
    a = monte_carlo_probability(gm, boxes_env, 3000, seed=11)
    b = monte_carlo_probability(gm, boxes_env, 3000, seed=11)
    c = monte_carlo_probability(gm, boxes_env, 3000, seed=12)
    assert a.hits == b.hits and a.hits != c.hits
    assert a.low <= a.probability <= a.high


def test_monte_carlo_converges_to_halfspace():
    from scipy.special import ndtr

    env = Environment.from_meshes([box_mesh([1, -100, -100], [200, 100, 100])])
    gm = GaussianMixture(np.ones(1), np.zeros((1, 3)), np.eye(3)[None])
    est = monte_carlo_probability(gm, env, 100_000, seed=0, confidence=0.999)
    assert est.low <= 1 - ndtr(1.0) <= est.high


def test_paths_collide():
    env = Environment.from_meshes([box_mesh([-0.01, -1, -1], [0.01, 1, 1])])
    paths = np.array(
        [[[-1.0, 0, 0], [1.0, 0, 0]], [[-1.0, 0, 0], [-0.5, 0, 0]], [[0.0, 0, 0], [0.0, 5, 0]]]
    )
    np.testing.assert_array_equal(paths_collide(paths, env), [True, False, True])
    np.testing.assert_array_equal(paths_collide(paths, env, segments=False), [False, False, True])


def test_bad_inputs(boxes_env):
    gm = GaussianMixture(np.ones(1), np.zeros((1, 3)), np.eye(3)[None])
    with pytest.raises(InvalidInputError, match="n_samples"):
        monte_carlo_probability(gm, boxes_env, 0)
    with pytest.raises(InvalidInputError, match="confidence"):
        binomial_interval(1, 10, 1.5)
    with pytest.raises(InvalidInputError, match="method"):
        binomial_interval(1, 10, 0.9, "jeffreys")
    with pytest.raises(InvalidInputError, match="paths"):
        paths_collide(np.zeros((3, 2)), boxes_env)
