"""Body-contact cloud risk (collision/body_risk.py) against closed forms: independent points
(ρ = 0) give 1 - (1 - p)^N, a rigid body of one point (ρ = 1) gives p, with p = 1 - Φ(b) for a
Gaussian b standard deviations from a half-space; trajectories share one draw per cloud."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

from riskplan.collision import Environment
from riskplan.collision.body_risk import (
    allocate_points,
    cloud_risk,
    sampled_body_gaps,
    sampled_body_risk,
)
from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import NumpyMixture
from tests.collision.conftest import box_mesh
from tests.conftest import TOL

SIGMA = 0.1
B = 2.0  # the mean is B standard deviations from the box face x = 0


@pytest.fixture(scope="module")
def slab():
    # a big box filling x > 0 near the origin: a half-space for the draws
    return Environment.from_meshes([box_mesh([0.0, -5.0, -5.0], [5.0, 5.0, 5.0])])


def one(mean_x=-B * SIGMA):
    return NumpyMixture.from_covariances(
        np.array([[1.0]]), np.array([[[mean_x, 0.0, 0.0]]]), np.eye(3)[None, None] * SIGMA**2
    )


def within(p_hat, p, n, z=4.5):
    return abs(p_hat - p) <= z * np.sqrt(max(p * (1 - p), 1e-12) / n) + 1 / n


@pytest.mark.parametrize("n_points", [1, 4, 16])
def test_independent_points_closed_form(slab, n_points):
    p = 1 - norm.cdf(B)
    r = cloud_risk(one(), slab, n_points=n_points, n_clouds=4000, coherence=0.0, seed=1)
    assert within(r.per_configuration[0], 1 - (1 - p) ** n_points, 4000)


def test_rigid_body_is_one_point(slab):
    """ρ = 1: every point of a cloud is the same draw, so N points collide as often as one."""
    p = 1 - norm.cdf(B)
    r = cloud_risk(one(), slab, n_points=64, n_clouds=4000, coherence=1.0, seed=2)
    assert within(r.per_configuration[0], p, 4000)
    # the counterfactual: independent points at the same marginal collide far more often
    r0 = cloud_risk(one(), slab, n_points=64, n_clouds=4000, coherence=0.0, seed=2)
    assert r0.per_configuration[0] > 10 * r.per_configuration[0]


def test_risk_grows_with_independence(slab):
    vals = [
        cloud_risk(one(), slab, n_points=32, n_clouds=2000, coherence=c, seed=3).per_configuration[
            0
        ]
        for c in (1.0, 0.9, 0.5, 0.0)
    ]
    assert vals == sorted(vals) and vals[-1] > vals[0]


def test_trajectory_shares_the_draw(slab):
    """Two identical configurations: with one shared draw per cloud the trajectory risk equals
    the per-configuration risk exactly (ρ = 1), not eq. 10's 1 - (1 - p)^2."""
    gm1 = one()
    gm = NumpyMixture(
        np.repeat(gm1.weights, 2, 0),
        np.repeat(gm1.means, 2, 0),
        np.repeat(gm1.precision_cholesky, 2, 0),
    )
    r = cloud_risk(gm, slab, n_points=8, n_clouds=3000, coherence=1.0, seed=4)
    assert r.per_configuration[0] == r.per_configuration[1] == r.trajectory
    assert r.hits.shape == (3000, 2)


def test_far_component_is_free_and_seeded(slab):
    far = cloud_risk(one(-20 * SIGMA), slab, n_clouds=200, seed=0)
    assert far.per_configuration[0] == 0.0 and far.trajectory == 0.0
    a = cloud_risk(one(), slab, n_clouds=300, seed=7).per_configuration
    b = cloud_risk(one(), slab, n_clouds=300, seed=7).per_configuration
    np.testing.assert_array_equal(a, b)


def test_allocate_points():
    w = np.array([[0.5, 0.3, 0.2], [0.34, 0.33, 0.33]])
    c = allocate_points(w, 10)
    np.testing.assert_array_equal(c.sum(-1), [10, 10])
    np.testing.assert_array_equal(c[0], [5, 3, 2])
    assert np.abs(c[1] - 10 * w[1]).max() < 1


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"coherence": 1.5}, "coherence"),
        ({"n_points": 0}, "n_points"),
        ({"n_clouds": 2.5}, "n_clouds"),
        ({"margin": float("nan")}, "margin"),
    ],
)
def test_errors(slab, kw, match):
    with pytest.raises(InvalidInputError, match=match):
        cloud_risk(one(), slab, **kw)


# --- sampled whole bodies (sampled_body_risk) ---------------------------------------------

BODY_SD = 0.1  # isotropic surface spread of the body piece
EXEC_SD = 0.1  # execution spread of its mean, normal to the face z = 0
EXTENT = 2.0


@pytest.fixture(scope="module")
def floor():
    # a big box filling z > 0 near the origin (the first lattice direction is nearly +z)
    return Environment.from_meshes([box_mesh([-5.0, -5.0, 0.0], [5.0, 5.0, 5.0])])


def body_case(gap_sds, n, seed):
    """One body piece whose ellipsoid (extent EXTENT) stays ``gap_sds`` execution standard
    deviations below the face; its predicted covariance folds in the execution spread."""
    mz = -(EXTENT * BODY_SD + gap_sds * EXEC_SD)
    cov = np.diag([BODY_SD**2, BODY_SD**2, BODY_SD**2 + EXEC_SD**2])
    nominal = NumpyMixture.from_covariances(
        np.array([[1.0]]), np.array([[[0.0, 0.0, mz]]]), cov[None, None]
    )
    z = np.random.default_rng(seed).standard_normal(n)
    drawn = np.zeros((n, 1, 1, 3))
    drawn[:, 0, 0, 2] = mz + EXEC_SD * z
    return nominal, drawn, z


@pytest.mark.parametrize("gap_sds", [0.0, 1.0, 2.0])
def test_sampled_bodies_closed_form(floor, gap_sds):
    """The piece touches iff its execution shift closes the gap: P = 1 - Φ(gap) (the surface
    spread is recovered by removing the executions' share from the predicted covariance)."""
    n = 4000
    nominal, drawn, _ = body_case(gap_sds, n, seed=7)
    r = sampled_body_risk(nominal, drawn, floor, extent=EXTENT)
    assert within(r.per_configuration[0], 1 - norm.cdf(gap_sds), n)
    # the counterfactual: without removing the executions' share the body is wider and the
    # same draws collide more often
    wide = np.zeros_like(drawn) + drawn.mean(axis=0)
    wide[:2] += np.array([0.0, 0.0, 1e-9])  # two draws so that S >= 2; no execution spread
    assert sampled_body_risk(nominal, wide, floor, extent=EXTENT).per_configuration[0] in (0, 1)


def test_sampled_bodies_are_the_draws(floor):
    """Sample by sample: a draw collides exactly when its shift closes the gap (up to the
    boundary lattice, whose pole is at cos = 1 - 1/n_directions)."""
    nominal, drawn, z = body_case(1.0, 2000, seed=8)
    r = sampled_body_risk(nominal, drawn, floor, extent=EXTENT, n_directions=4096)
    sure = np.abs(z - 1.0) > 0.05  # away from the boundary of the decision
    assert np.array_equal(r.hits[sure, 0], (z > 1.0)[sure])


def test_sampled_bodies_trajectory_keeps_the_draw(floor):
    nominal, drawn, _ = body_case(1.0, 1000, seed=9)
    gm = NumpyMixture(
        np.repeat(nominal.weights, 2, 0),
        np.repeat(nominal.means, 2, 0),
        np.repeat(nominal.precision_cholesky, 2, 0),
    )
    r = sampled_body_risk(gm, np.repeat(drawn, 2, axis=1), floor, extent=EXTENT)
    assert r.per_configuration[0] == r.per_configuration[1] == r.trajectory
    assert r.hits.shape == (1000, 2)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(extent=0.0), "extent"),
        (dict(n_directions=0), "n_directions"),
        (dict(drawn=np.zeros((1, 1, 1, 3))), "drawn_means"),
        (dict(drawn=np.full((3, 1, 1, 3), np.nan)), "drawn_means"),
    ],
)
def test_sampled_bodies_errors(floor, kw, match):
    nominal, drawn, _ = body_case(1.0, 10, seed=0)
    drawn = kw.pop("drawn", drawn)
    with pytest.raises(InvalidInputError, match=match):
        sampled_body_risk(nominal, drawn, floor, **kw)


def test_sampled_body_gaps_closed_form(floor):
    """Below a flat face the clearance of a sampled body is exact: the depth of its centre
    less the piece's reach along the normal, ``extent * sqrt(Σ_zz - var_s μ_z)`` (the
    executions' share removed); ``g < 0`` is the collision decision of sampled_body_risk."""
    nominal, drawn, z = body_case(1.0, 2000, seed=8)
    g = sampled_body_gaps(nominal, drawn, floor, extent=EXTENT)
    mz = drawn[:, 0, 0, 2]
    reach = EXTENT * np.sqrt(BODY_SD**2 + EXEC_SD**2 - mz.var(ddof=1))
    np.testing.assert_allclose(g[:, 0], -mz - reach, **TOL["float64_exact"])
    r = sampled_body_risk(nominal, drawn, floor, extent=EXTENT, n_directions=4096)
    sure = np.abs(z - 1.0) > 0.05  # away from the boundary lattice's resolution
    assert np.array_equal((g[:, 0] < 0)[sure], r.hits[sure, 0])
    with pytest.raises(InvalidInputError, match="drawn_means"):
        sampled_body_gaps(nominal, drawn[:1], floor)
