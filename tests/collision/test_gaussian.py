"""Patil-2012 bound for single Gaussians: closed forms, oracles, Monte Carlo, batching."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import ndtr

from riskplan.collision import (
    Environment,
    free_region,
    gaussian_bound,
    gaussian_bound_terms,
    mahalanobis,
    monte_carlo_probability,
    precision_cholesky_from_covariance,
    unwhiten,
    whiten,
)
from riskplan.errors import InvalidInputError
from riskplan.kinematics import GaussianMixture
from tests.collision.conftest import box_mesh, random_upper
from tests.conftest import TOL


def naive_patil(V, F, mu, U):
    """Reference: the published loop, in plain Python over all faces, no cut-off."""
    W = (V - mu) @ U.T
    import riskplan.collision._kernels as K

    tri = W[F]
    _dist, _cp, _ = K.closest_points_brute(W, F, np.zeros((1, W.shape[1])))
    # distances of every face to the origin
    d_all = np.array(
        [
            K.closest_points_brute(W, F[i : i + 1], np.zeros((1, W.shape[1])))[0][0]
            for i in range(len(F))
        ]
    )
    c_all = np.array(
        [
            K.closest_points_brute(W, F[i : i + 1], np.zeros((1, W.shape[1])))[1][0]
            for i in range(len(F))
        ]
    )
    active = list(range(len(F)))
    bs = []
    while active:
        j = min(active, key=lambda i: d_all[i])
        b = d_all[j]
        a = c_all[j] / b
        bs.append(b)
        active = [
            i
            for i in active
            if i != j and not np.all(tri[i] @ a >= b - TOL["on_surface"]["atol"] * (1 + b))
        ]
    return np.sum(ndtr(-np.array(bs))), len(bs)


def test_halfspace_closed_form_3d():
    # a large box whose nearest face is the plane x = b / s: the bound is 1 - Phi(b) exactly
    for b, s in ((0.5, 1.0), (2.0, 0.3), (3.7, 2.0)):
        env = Environment.from_meshes([box_mesh([b * s, -50, -50], [b * s + 100, 50, 50])])
        U = np.eye(3) / s
        np.testing.assert_allclose(
            gaussian_bound(np.zeros(3), U, env), 1 - ndtr(b), **TOL["float64_ref"]
        )


def test_halfspace_closed_form_2d_anisotropic():
    # obstacle edge x = 1 facing the mean; sigma_x = 0.4 gives b = 2.5 whatever sigma_y and the correlation
    env = Environment.from_polygons([[[1, -100], [200, -100], [200, 100], [1, 100]]])
    cov = np.array([[0.16, 0.1], [0.1, 0.5]])
    U = precision_cholesky_from_covariance(cov)
    np.testing.assert_allclose(
        gaussian_bound(np.zeros(2), U, env), 1 - ndtr(2.5), **TOL["float64_ref"]
    )


def test_far_obstacle_is_zero_and_inside_is_at_least_half(boxes_env):
    assert gaussian_bound(np.array([50.0, 50, 50]), np.eye(3), boxes_env) < TOL["round_off"]["atol"]
    inside = gaussian_bound(np.array([1.5, 0, 0]), np.eye(3) * 10, boxes_env)
    assert inside >= 0.5
    terms = gaussian_bound_terms(
        np.array([[1.5, 0, 0], [0, 0, 0]]), np.stack([np.eye(3)] * 2), boxes_env
    )
    np.testing.assert_array_equal(terms.mean_in_collision, [True, False])


def test_whitening_commutes_with_geometry(rng, boxes_env):
    # distance in the whitened environment = Mahalanobis distance of the same point
    for _ in range(5):
        mu = rng.normal(size=3) * 0.3
        U = random_upper(rng, 3)
        wenv = boxes_env.whitened(mu, U)
        dw, cw, _ = wenv.closest_points(np.zeros(3))
        x = unwhiten(cw[None], mu, U)[0]
        np.testing.assert_allclose(mahalanobis(x[None], mu, U)[0], dw, **TOL["float64_ref"])
        # x is on the original surface, and no surface point is Mahalanobis-closer
        assert boxes_env.closest_points(x)[0] < TOL["on_surface"]["atol"]
        import trimesh

        pts, _ = trimesh.sample.sample_surface(boxes_env.to_trimesh(), 20000, seed=1)
        assert mahalanobis(pts, mu, U).min() >= dw - TOL["on_surface"]["atol"]
        np.testing.assert_allclose(
            whiten(unwhiten(cw[None], mu, U), mu, U)[0], cw, **TOL["float64_ref"]
        )
        # the first Patil constraint is that closest point
        fr = free_region(mu, U, boxes_env)
        np.testing.assert_allclose(fr.distances.min(), dw, **TOL["float64_ref"])


def test_fast_equals_naive(rng, boxes_env):
    for _ in range(6):
        mu = rng.normal(size=3) * 0.4
        U = random_upper(rng, 3, scale=1.5)
        ref, ncons = naive_patil(boxes_env.vertices, boxes_env.faces, mu, U)
        terms = gaussian_bound_terms(mu, U, boxes_env, cutoff=math.inf)
        np.testing.assert_allclose(terms.halfspace_sum, ref, **TOL["float64_ref"])
        assert terms.n_constraints == ncons
        # the cut-off changes the bound by at most the chi tail
        np.testing.assert_allclose(
            gaussian_bound(mu, U, boxes_env), min(1.0, ref), **TOL["cutoff_tail"]
        )


def test_free_region_is_free(rng, boxes_env):
    mu, U = np.array([0.1, -0.2, 0.0]), random_upper(rng, 3)
    fr = free_region(mu, U, boxes_env)
    pts = mu + rng.normal(size=(20000, 3)) * 2.0
    inside_poly = np.all(pts @ fr.normals.T <= fr.offsets - TOL["on_surface"]["atol"], axis=1)
    assert inside_poly.sum() > 100
    assert not boxes_env.contains(pts[inside_poly]).any()


def test_batch_equals_loop(rng, boxes_env):
    mus = rng.normal(size=(4, 3, 3)) * 0.5
    Us = np.stack([np.stack([random_upper(rng, 3) for _ in range(3)]) for _ in range(4)])
    batch = gaussian_bound(mus, Us, boxes_env)
    assert batch.shape == (4, 3)
    loop = np.array(
        [[gaussian_bound(mus[i, j], Us[i, j], boxes_env) for j in range(3)] for i in range(4)]
    )
    np.testing.assert_allclose(batch, loop, **TOL["float64_exact"])


@settings(max_examples=12, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**31 - 1),
    dim=st.sampled_from([2, 3]),
    scale=st.floats(0.2, 1.5),
)
def test_bound_never_below_monte_carlo(seed, dim, scale):
    rng = np.random.default_rng(seed)
    if dim == 3:
        meshes = []
        for _ in range(3):
            c = rng.uniform(-2, 2, 3)
            e = rng.uniform(0.3, 1.5, 3)
            meshes.append(box_mesh(c - e / 2, c + e / 2))
        env = Environment.from_meshes(meshes)
    else:
        polys = []
        for _ in range(3):
            c = rng.uniform(-2, 2, 2)
            k = rng.integers(3, 8)
            ang = 2 * np.pi * (np.arange(k) + rng.uniform(0, 0.8, k)) / k  # star-shaped about c
            r = rng.uniform(0.3, 1.0, k)
            polys.append(c + np.column_stack([r * np.cos(ang), r * np.sin(ang)]))
        env = Environment.from_polygons(polys)
    mu = rng.uniform(-1, 1, dim)
    if env.contains(mu):
        mu = mu + 10.0  # keep the mean free (the bound is 1 otherwise, trivially valid)
    U = random_upper(rng, dim, scale=scale)
    bound = gaussian_bound(mu, U, env)
    gm = GaussianMixture(np.ones(1), mu[None], U[None])
    mc = monte_carlo_probability(
        gm, env, 4000, seed=seed, confidence=0.999, interval="clopper-pearson"
    )
    assert 0.0 <= bound <= 1.0
    assert bound >= mc.low - TOL["float64_abs"]["atol"]


def test_extruded_2d_agrees_with_3d(rng):
    polys = [
        np.array([[1.0, -1], [2, -1], [2, 1], [1, 1]]),
        np.array([[-2.0, 0.5], [-0.8, 0.7], [-1.2, 1.8]]),
        np.array([[-0.5, -2.0], [0.5, -2.2], [0.7, -1.4], [-0.4, -1.2]]),
    ]
    env2 = Environment.from_polygons(polys)
    env3 = env2.extrude(-20.0, 20.0)  # caps at whitened |z| = 200, far beyond the cut-off
    for _ in range(6):
        mu2 = rng.normal(size=2) * 0.3
        U2 = random_upper(rng, 2)
        U3 = np.zeros((3, 3))
        U3[:2, :2] = U2
        U3[2, 2] = 1.0 / 0.1
        p2 = gaussian_bound(mu2, U2, env2)
        p3 = gaussian_bound(np.r_[mu2, 0.0], U3, env3)
        np.testing.assert_allclose(p3, p2, **TOL["extruded_2d"])
        pts = rng.normal(size=(200, 2)) * 2
        np.testing.assert_array_equal(
            env3.contains(np.column_stack([pts, np.zeros(200)])), env2.contains(pts)
        )


def test_bad_inputs(boxes_env):
    with pytest.raises(InvalidInputError, match="means"):
        gaussian_bound(np.zeros(2), np.eye(2), boxes_env)
    with pytest.raises(InvalidInputError, match="NaN"):
        gaussian_bound(np.array([np.nan, 0, 0]), np.eye(3), boxes_env)
    with pytest.raises(InvalidInputError, match="upper triangular"):
        gaussian_bound(np.zeros(3), np.ones((3, 3)), boxes_env)
    with pytest.raises(InvalidInputError, match="positive"):
        gaussian_bound(np.zeros(3), -np.eye(3), boxes_env)
    with pytest.raises(InvalidInputError, match="positive definite"):
        precision_cholesky_from_covariance(np.diag([1.0, -1.0, 1.0]))
    with pytest.raises(InvalidInputError, match="NaN"):
        precision_cholesky_from_covariance(np.diag([1.0, np.inf, 1.0]))
    with pytest.raises(InvalidInputError, match="symmetric"):
        precision_cholesky_from_covariance(np.array([[1.0, 0.5], [0.0, 1.0]]))
    with pytest.raises(InvalidInputError, match="Environment"):
        gaussian_bound(np.zeros(3), np.eye(3), "mesh")


def test_precision_cholesky_from_covariance_roundtrip(rng):
    A = rng.normal(size=(3, 3))
    cov = A @ A.T + np.eye(3)
    U = precision_cholesky_from_covariance(cov)
    np.testing.assert_allclose(U.T @ U, np.linalg.inv(cov), **TOL["float64_ref"])
    assert np.allclose(np.tril(U, -1), 0)


def test_covariance_front_end_2d_lqg_case():
    # LQG-MP style: a 2-D state Gaussian per time step against a polygon; equals the U form
    env = Environment.from_polygons([[[1, -100], [200, -100], [200, 100], [1, 100]]])
    means = np.array([[0.0, 0.0], [0.5, 3.0]])
    covs = np.stack([np.diag([0.25, 1.0]), np.array([[0.04, 0.01], [0.01, 0.09]])])
    from riskplan.collision import gaussian_bound_covariance

    got = gaussian_bound_covariance(means, covs, env)
    np.testing.assert_allclose(got, [1 - ndtr(2.0), 1 - ndtr(0.5 / 0.2)], **TOL["float64_ref"])
    with pytest.raises(InvalidInputError, match="positive definite"):
        gaussian_bound_covariance(means, -covs, env)


@pytest.mark.parametrize("s", [1e200, 1e150, 1e8, 1.0])
def test_extreme_precision_scales_keep_the_closed_form(s):
    # precision U = s I, the face x = 0 of a large box at distance 3 / s from the mean (whitened
    # distance 3): the bound is 1 - Phi(3) at every scale, although the whitened box is up to
    # 1e202 wide (no overflow, and the distance is exact relative to itself, not to the face)
    env = Environment.from_meshes([box_mesh([0.0, -100.0, -100.0], [100.0, 100.0, 100.0])])
    # (the half-space sum: whether a point 3e-200 from a face is outside is beyond the winding
    # number's resolution, where the bound is 1 - conservative)
    got = gaussian_bound_terms(np.array([-3.0 / s, 0.0, 0.0]), s * np.eye(3), env)
    np.testing.assert_allclose(got.halfspace_sum, 1 - ndtr(3.0), **TOL["float64_ref"])
    assert got.n_constraints == 1


@pytest.mark.parametrize(
    "U",
    [
        6e78 * np.eye(3),  # very thin covariance
        1e200 * np.eye(3),
        1e300 * np.eye(3),
        np.array([[1.0, 1e100, -1e100], [0.0, 1.0, 1e100], [0.0, 0.0, 1.0]]),  # huge off-diagonal
        np.array([[1e-300, 1e300, 1e300], [0.0, 1e300, -1e300], [0.0, 0.0, 5e-324]]),
        1e-300 * np.eye(3),  # covariance far wider than the scene
    ],
)
def test_valid_extreme_factors_give_a_probability(boxes_env, U):
    # these used to give NaN (a planner compares NaN < threshold as False: "safe") or a
    # ZeroDivisionError inside the compiled kernel
    for mean in (np.zeros(3), np.array([0.3, -0.7, 0.2]), np.array([1e300, -1e300, 0.0])):
        p = gaussian_bound(mean, U, boxes_env)
        assert np.isfinite(p) and 0.0 <= p <= 1.0
        region = free_region(mean, U, boxes_env)
        assert np.all(np.isfinite(region.distances)) and np.all(region.distances >= 0)


def test_huge_covariance_through_the_covariance_front_end(boxes_env):
    from riskplan.collision import gaussian_bound_covariance

    p = gaussian_bound_covariance(np.zeros(3), 1e100 * np.eye(3), boxes_env)
    assert np.isfinite(p) and 0.0 <= p <= 1.0


def test_probability_of_collision_rejects_a_missing_environment():
    from riskplan.collision import monte_carlo_probability, probability_of_collision

    gm = GaussianMixture([1.0], [[0.0, 0.0, 0.0]], np.eye(3)[None])
    for method in ("bound", "union", "monte_carlo"):
        with pytest.raises(InvalidInputError, match="environment"):
            probability_of_collision(gm, None, method)
    with pytest.raises(InvalidInputError, match="environment"):
        monte_carlo_probability(gm, "chest.stl", 10)
