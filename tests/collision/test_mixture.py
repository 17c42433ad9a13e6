"""Mixture bound (eq. 9) and its union variant; the batched probability_of_collision API."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.special import ndtr

from riskplan.collision import (
    Environment,
    component_bounds,
    gaussian_bound,
    mixture_bound,
    monte_carlo_probability,
    probability_of_collision,
)
from riskplan.errors import InvalidInputError
from riskplan.kinematics import GaussianMixture
from tests.collision.conftest import box_mesh, random_upper
from tests.conftest import TOL


@pytest.fixture(scope="module")
def wall_env():
    # half-space-like wall x >= 1 (a huge box)
    return Environment.from_meshes([box_mesh([1, -100, -100], [200, 100, 100])])


def _mixture(rng, batch, K, d=3, spread=0.5):
    w = rng.dirichlet(np.ones(K), size=batch)
    m = rng.normal(size=(*batch, K, d)) * spread
    u = np.stack([random_upper(rng, d) for _ in range(int(np.prod(batch)) * K)]).reshape(
        *batch, K, d, d
    )
    return GaussianMixture(w, m, u)


def test_closed_form_two_components(wall_env):
    # components at x = 0 and x = -1 with sigma_x = 0.5: b = 2 and 4
    gm = GaussianMixture.from_covariances(
        np.array([0.3, 0.7]),
        np.array([[0.0, 0, 0], [-1.0, 0, 0]]),
        np.stack([np.eye(3) * 0.25] * 2),
    )
    p1, p2 = 1 - ndtr(2.0), 1 - ndtr(4.0)
    np.testing.assert_allclose(
        probability_of_collision(gm, wall_env), 0.3 * p1 + 0.7 * p2, **TOL["float64_ref"]
    )
    np.testing.assert_allclose(
        probability_of_collision(gm, wall_env, "union"), p1 + p2, **TOL["float64_ref"]
    )


def test_single_component_equals_gaussian(rng, boxes_env):
    gm = _mixture(rng, (4,), 1)
    a = gm.numpy()
    np.testing.assert_allclose(
        probability_of_collision(gm, boxes_env),
        gaussian_bound(a["means"][:, 0], a["precision_cholesky"][:, 0], boxes_env),
        **TOL["float64_exact"],
    )


def test_batch_equals_loop_and_range(rng, boxes_env):
    gm = _mixture(rng, (3, 4), 5)
    for method in ("bound", "union"):
        p = probability_of_collision(gm, boxes_env, method)
        assert p.shape == (3, 4)
        assert np.all((p >= 0) & (p <= 1))
        loop = np.array(
            [
                [probability_of_collision(gm[i, j], boxes_env, method) for j in range(4)]
                for i in range(3)
            ]
        )
        np.testing.assert_allclose(p, loop, **TOL["float64_exact"])
    assert np.all(
        probability_of_collision(gm, boxes_env, "union")
        >= probability_of_collision(gm, boxes_env) - TOL["round_off"]["atol"]
    )


def test_float32_torch_mixture_accepted(rng, boxes_env):
    gm = _mixture(rng, (2,), 3)
    gm32 = gm.to(torch.float32)
    np.testing.assert_allclose(
        probability_of_collision(gm32, boxes_env),
        probability_of_collision(gm, boxes_env),
        **TOL["float32_ref"],
    )


def test_bounds_cover_monte_carlo(rng, boxes_env):
    gm = _mixture(rng, (6,), 4, spread=0.8)
    for combine, method in (("weighted", "bound"), ("union", "union")):
        p = probability_of_collision(gm, boxes_env, method)
        mc = monte_carlo_probability(gm, boxes_env, 4000, combine=combine, seed=3, confidence=0.999)
        assert np.all(p >= mc.low - TOL["float64_abs"]["atol"]), (combine, p, mc.low)
    # the Monte Carlo front end returns the point estimate with the same shape
    est = probability_of_collision(gm, boxes_env, "monte_carlo", n_samples=500, seed=1)
    assert est.shape == (6,)


def test_mean_inside_component_counts_fully(boxes_env):
    gm = GaussianMixture.from_covariances(
        np.array([0.25, 0.75]),
        np.array([[1.5, 0, 0], [0.0, 0, 5.0]]),
        np.stack([np.eye(3) * 1e-4] * 2),
    )
    p, _w = component_bounds(gm, boxes_env)
    np.testing.assert_allclose(p, [1.0, 0.0], **TOL["float64_abs"])
    np.testing.assert_allclose(probability_of_collision(gm, boxes_env), 0.25, **TOL["float64_abs"])


def test_two_dimensional_mixture():
    env = Environment.from_polygons([[[1, -50], [100, -50], [100, 50], [1, 50]]])
    gm = GaussianMixture.from_covariances(
        np.array([0.5, 0.5]), np.array([[0.0, 0.0], [0.5, 3.0]]), np.stack([np.eye(2) * 0.25] * 2)
    )
    np.testing.assert_allclose(
        probability_of_collision(gm, env),
        0.5 * (1 - ndtr(2.0)) + 0.5 * (1 - ndtr(1.0)),
        **TOL["float64_ref"],
    )


def test_bad_inputs(rng, boxes_env):
    gm2 = GaussianMixture(np.ones(1), np.zeros((1, 2)), np.eye(2)[None])
    with pytest.raises(InvalidInputError, match="dimension"):
        probability_of_collision(gm2, boxes_env)
    bad_w = GaussianMixture(
        np.array([0.5, 0.6]), np.zeros((2, 3)), np.stack([np.eye(3)] * 2), validate=False
    )
    with pytest.raises(InvalidInputError, match="sum to 1"):
        probability_of_collision(bad_w, boxes_env)
    bad_u = GaussianMixture(np.ones(1), np.zeros((1, 3)), -np.eye(3)[None], validate=False)
    with pytest.raises(InvalidInputError, match="positive"):
        probability_of_collision(bad_u, boxes_env)
    nan_m = GaussianMixture(np.ones(1), np.full((1, 3), np.nan), np.eye(3)[None], validate=False)
    with pytest.raises(InvalidInputError, match="NaN"):
        probability_of_collision(nan_m, boxes_env)
    with pytest.raises(
        InvalidInputError, match=r"not symmetric positive definite|positive definite"
    ):
        GaussianMixture.from_covariances(np.ones(1), np.zeros((1, 3)), -np.eye(3)[None])
    gm = _mixture(rng, (2,), 2)
    with pytest.raises(InvalidInputError, match="method"):
        probability_of_collision(gm, boxes_env, "nope")
    with pytest.raises(InvalidInputError, match="combine"):
        mixture_bound(gm, boxes_env, combine="max")
    with pytest.raises(InvalidInputError, match="GaussianMixture"):
        probability_of_collision(np.zeros(3), boxes_env)
