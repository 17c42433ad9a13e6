"""Property-based tests of the collision entry points (see tests/properties.py for the contract)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from riskplan.collision import (
    BasePose,
    Environment,
    gaussian_bound,
    gaussian_bound_covariance,
    precision_cholesky_from_covariance,
    probability_of_collision,
)
from riskplan.kinematics import GaussianMixture
from tests.collision.conftest import box_mesh
from tests.conftest import TOL
from tests.properties import (
    PROPERTY,
    any_float,
    arrays_or_junk,
    assert_finite,
    assert_probability,
    call,
    finite_float,
    junk,
)

ENV = Environment.from_meshes(
    [
        box_mesh([0.05, -0.05, -0.05], [0.1, 0.05, 0.05]),
        box_mesh([-0.1, -0.1, 0.2], [0.1, 0.1, 0.25]),
    ]
)
ENV2 = Environment.from_polygons([[[1, -1], [2, -1], [2, 1], [1, 1]]])

# wide range of magnitudes (1e-300 .. 1e300, both signs) for valid-but-extreme factors
magnitudes = st.floats(min_value=-300, max_value=300).map(lambda e: 10.0**e)
signed = st.tuples(magnitudes, st.sampled_from([-1.0, 1.0])).map(lambda t: t[0] * t[1])


@st.composite
def upper_factors(draw, d=3):
    u = np.zeros((d, d))
    for i in range(d):
        u[i, i] = draw(magnitudes)
        for j in range(i + 1, d):
            u[i, j] = draw(st.one_of(st.just(0.0), signed))
    return u


@PROPERTY
@given(mean=hnp.arrays(np.float64, 3, elements=st.one_of(finite_float, signed)), u=upper_factors())
def test_valid_gaussians_give_a_probability(mean, u):
    # valid input: the result must be a number in [0, 1] (a named error is not acceptable here)
    assert_probability(gaussian_bound(mean, u, ENV))


@PROPERTY
@given(mean=arrays_or_junk(), u=arrays_or_junk())
def test_arbitrary_gaussian_input(mean, u):
    p = call(gaussian_bound, mean, u, ENV)
    if p is not None:
        assert_probability(p)
    p = call(gaussian_bound, mean, u, ENV2)
    if p is not None:
        assert_probability(p)


@PROPERTY
@given(
    mean=hnp.arrays(np.float64, 3, elements=finite_float),
    cov=arrays_or_junk(hnp.array_shapes(min_dims=2, max_dims=3, min_side=3, max_side=3)),
)
def test_arbitrary_covariances(mean, cov):
    u = call(precision_cholesky_from_covariance, cov)
    if u is not None:
        assert_finite(u)
    p = call(gaussian_bound_covariance, mean, cov, ENV)
    if p is not None:
        assert_probability(p)


@PROPERTY
@given(
    w=arrays_or_junk(),
    m=arrays_or_junk(),
    u=arrays_or_junk(),
    method=st.sampled_from(["bound", "union", "monte_carlo", "x"]),
)
def test_arbitrary_mixtures(w, m, u, method):
    gm = call(GaussianMixture, w, m, u)
    if gm is None:
        return
    p = call(probability_of_collision, gm, ENV, method, n_samples=64, seed=0)
    if p is not None:
        assert_probability(p)


@PROPERTY
@given(
    text=st.one_of(
        st.text(max_size=40),
        st.lists(any_float, max_size=8).map(lambda v: ",".join(map(str, v))),
        junk(),
    )
)
def test_arbitrary_base_poses(text):
    pose = call(BasePose.parse, text)
    if pose is not None:
        assert_finite(pose.position, pose.rotation)
        np.testing.assert_allclose(
            pose.rotation.T @ pose.rotation, np.eye(3), **TOL["orthonormality"]
        )


@pytest.mark.parametrize("points", [np.full((2, 3), np.nan), np.zeros((0, 3)), np.zeros(3)])
def test_queries_on_edge_shapes(points):
    r = call(ENV.contains, points)
    if r is not None:
        assert r.dtype == bool
