"""The NumPy mixture core against independent oracles (SciPy densities, closed-form moments,
batch vs loop) and against the torch GaussianMixture built on it (float64)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.stats import multivariate_normal

from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import (
    NumpyMixture,
    as_numpy_mixture,
    precision_cholesky_from_covariances,
)
from riskplan.kinematics import GaussianMixture

# z-score beyond which a Monte Carlo moment is called wrong (the chance of a false alarm for one
# comparison is below 1e-6; moments of independent draws are close to normal at these n)
Z = 5.0


def _random_mixture(rng, batch=(), K=4, d=3):
    A = rng.normal(size=batch + (K, d, d))
    cov = A @ np.swapaxes(A, -1, -2) + 0.3 * np.eye(d)
    w = rng.dirichlet(np.ones(K), size=batch) if batch else rng.dirichlet(np.ones(K))
    mu = rng.normal(size=batch + (K, d))
    return w, mu, cov


def _moments_loop(w, mu, cov):
    """Mean and covariance of one mixture from ``E[x x^T] = sum_k w_k (Sigma_k + mu_k mu_k^T)``."""
    mean = sum(w[k] * mu[k] for k in range(len(w)))
    second = sum(w[k] * (cov[k] + np.outer(mu[k], mu[k])) for k in range(len(w)))
    return mean, second - np.outer(mean, mean)


def _assert_sample_moments(x, mean, cov):
    """Sample mean and covariance of draws ``x (n, d)`` within ``Z`` standard errors of the
    exact ``mean`` and ``cov`` (the covariance entries' errors estimated from the draws)."""
    n = len(x)
    dev = x - mean
    se_mean = np.sqrt(np.diag(cov) / n)
    assert np.all(np.abs(x.mean(0) - mean) < Z * se_mean), (x.mean(0), mean)
    prod = dev[:, :, None] * dev[:, None, :]  # (n, d, d)
    se_cov = prod.std(0) / np.sqrt(n)
    sample_cov = prod.mean(0) - np.outer(dev.mean(0), dev.mean(0))
    assert np.all(np.abs(sample_cov - cov) < Z * se_cov), (sample_cov, cov)


@pytest.mark.parametrize("d", [1, 2, 3])
def test_log_prob_matches_scipy(rng, tol, d):
    w, mu, cov = _random_mixture(rng, K=4, d=d)
    gm = NumpyMixture.from_covariances(w, mu, cov)
    x = rng.normal(size=(11, d)) * 2
    ref = np.log(sum(w[k] * multivariate_normal(mu[k], cov[k]).pdf(x) for k in range(4)))
    np.testing.assert_allclose(gm.log_prob(x), ref, **tol["float64_ref"])
    np.testing.assert_allclose(gm.covariances, cov, **tol["float64_ref"])
    np.testing.assert_allclose(gm.precisions, np.linalg.inv(cov), **tol["float64_ref"])


def test_numpy_and_torch_agree(rng, tol):
    w, mu, cov = _random_mixture(rng, batch=(2, 3))
    nm = NumpyMixture.from_covariances(w, mu, cov)
    tm = GaussianMixture.from_covariances(w, mu, cov)
    # one covariance -> factor conversion serves both types
    np.testing.assert_array_equal(tm.precision_cholesky.numpy(), nm.precision_cholesky)
    x = rng.normal(size=(2, 3, 7, 3)) * 3
    np.testing.assert_allclose(
        nm.component_log_prob(x), tm.component_log_prob(x).numpy(), **tol["float64_exact"]
    )
    np.testing.assert_allclose(nm.log_prob(x), tm.log_prob(x).numpy(), **tol["float64_exact"])
    np.testing.assert_allclose(nm.covariances, tm.covariances.numpy(), **tol["float64_exact"])
    np.testing.assert_allclose(nm.precisions, tm.precisions.numpy(), **tol["float64_exact"])
    # points broadcast against the batch shape the same way
    np.testing.assert_allclose(
        nm.log_prob(x[0, 0]), tm.log_prob(x[0, 0]).numpy(), **tol["float64_exact"]
    )


def test_batch_equals_loop(rng, tol):
    w, mu, cov = _random_mixture(rng, batch=(2, 3))
    gm = NumpyMixture.from_covariances(w, mu, cov)
    x = rng.normal(size=(2, 3, 5, 3))
    lp, mean, full = gm.log_prob(x), gm.mean(), gm.covariance()
    assert lp.shape == (2, 3, 5) and mean.shape == (2, 3, 3) and full.shape == (2, 3, 3, 3)
    for i in range(2):
        for j in range(3):
            one = gm[i, j]
            assert one.batch_shape == ()
            np.testing.assert_allclose(one.log_prob(x[i, j]), lp[i, j], **tol["float64_exact"])
            m_ref, c_ref = _moments_loop(w[i, j], mu[i, j], cov[i, j])
            np.testing.assert_allclose(mean[i, j], m_ref, **tol["float64_exact"])
            np.testing.assert_allclose(full[i, j], c_ref, **tol["float64_ref"])


def test_sample_moments_numpy_and_torch(rng):
    w, mu, cov = _random_mixture(rng, K=3)
    nm = NumpyMixture.from_covariances(w, mu, cov)
    mean, full = _moments_loop(w, mu, cov)
    n = 200_000
    _assert_sample_moments(nm.sample(n, seed=5), mean, full)
    _assert_sample_moments(
        GaussianMixture.from_covariances(w, mu, cov).sample(n, seed=5).numpy(), mean, full
    )


def test_sample_per_component_weights(rng):
    # components far apart: the fraction of draws near each mean is its weight (binomial)
    w = np.array([0.2, 0.5, 0.3])
    mu = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0]])
    gm = NumpyMixture.from_covariances(w, mu, np.stack([np.eye(2)] * 3))
    n = 100_000
    x = gm.sample(n, seed=1)
    nearest = np.argmin(((x[:, None, :] - mu) ** 2).sum(-1), axis=1)
    frac = np.bincount(nearest, minlength=3) / n
    assert np.all(np.abs(frac - w) < Z * np.sqrt(w * (1 - w) / n))


def test_sample_seeded_batched_and_empty(rng):
    w, mu, cov = _random_mixture(rng, batch=(4,))
    gm = NumpyMixture.from_covariances(w, mu, cov)
    a, b = gm.sample(10, seed=3), gm.sample(10, seed=np.random.default_rng(3))
    assert a.shape == (4, 10, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, gm.sample(10, seed=4))
    assert gm.sample(0, seed=0).shape == (4, 0, 3)
    with pytest.raises(InvalidInputError, match="n"):
        gm.sample(-1)


def test_conversions(rng, tol):
    w, mu, cov = _random_mixture(rng, batch=(2,))
    tm = GaussianMixture.from_covariances(w, mu, cov)
    nm = tm.to_numpy()
    for name, arr in tm.numpy().items():
        np.testing.assert_array_equal(getattr(nm, name), arr)
        assert getattr(nm, name).dtype == np.float64
    back = GaussianMixture.from_numpy_mixture(nm)
    x = rng.normal(size=(5, 3))
    np.testing.assert_array_equal(back.log_prob(x).numpy(), tm.log_prob(x).numpy())
    # float32 tensors become float64 arrays; values unchanged
    nm32 = tm.to(torch.float32).to_numpy()
    assert nm32.means.dtype == np.float64
    np.testing.assert_array_equal(nm32.means, tm.means.to(torch.float32).double().numpy())
    # as_numpy_mixture: either type, or any object with the three arrays
    assert as_numpy_mixture(nm) is nm
    np.testing.assert_array_equal(as_numpy_mixture(tm).weights, nm.weights)

    class Duck:
        weights, means, precision_cholesky = nm.weights, nm.means, nm.precision_cholesky

    np.testing.assert_array_equal(as_numpy_mixture(Duck()).means, nm.means)
    with pytest.raises(InvalidInputError, match="GaussianMixture"):
        as_numpy_mixture(np.zeros(3))


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda w, m, u: (w * 2, m, u), "sum to 1"),
        (lambda w, m, u: (w, m[..., :2], u), "precision_cholesky"),
        (lambda w, m, u: (w, m, np.swapaxes(u, -1, -2)), "upper triangular"),
        (lambda w, m, u: (w, m, -u), "positive"),
        (lambda w, m, u: (w, m * np.nan, u), "NaN"),
        (lambda w, m, u: (w[..., :2], m, u), "weights"),
        (lambda w, m, u: (-w, m, u), "non-negative"),
        (lambda w, m, u: (w.astype(complex), m, u), "numeric"),
    ],
)
def test_invalid_parameters_rejected_alike(rng, mutate, match):
    w, mu, cov = _random_mixture(rng)
    args = mutate(*NumpyMixture.from_covariances(w, mu, cov).numpy().values())
    with pytest.raises(InvalidInputError, match=match):
        NumpyMixture(*args)
    if match != "numeric":  # torch has its own dtype check
        with pytest.raises(InvalidInputError, match=match):
            GaussianMixture(*args)
    with pytest.raises(InvalidInputError, match=match):  # converting re-validates
        as_numpy_mixture(NumpyMixture(*args, validate=False))


def test_non_pd_covariance_rejected():
    with pytest.raises(InvalidInputError, match="positive definite"):
        precision_cholesky_from_covariances(np.array([[1.0, 2.0], [2.0, 1.0]]))
    with pytest.raises(InvalidInputError, match="NaN"):
        NumpyMixture.from_covariances([1.0], [[0.0]], [[[np.nan]]])


@pytest.mark.parametrize(
    "points, match",
    [
        (np.full((2, 3), np.nan), "NaN"),
        (np.zeros(3), r"\(\.\.\., N, 3\)"),
        (np.zeros((4, 2)), r"\(\.\.\., N, 3\)"),
        (None, "numeric"),
        ("0,0,0", "numeric"),
        (np.zeros((2, 3), dtype=complex), "numeric"),
        (np.zeros((5, 4, 3)), "broadcast"),
    ],
)
def test_log_prob_rejects_bad_points(rng, points, match):
    w, mu, cov = _random_mixture(rng, batch=(2,))
    gm = NumpyMixture.from_covariances(w, mu, cov)
    with pytest.raises(InvalidInputError, match=match):
        gm.log_prob(points)


def test_far_points_and_zero_weights():
    # U (x - mu) overflows with opposite signs (inf - inf): log density -inf, as in torch
    u = np.array([[[1e300, 1e300], [0.0, 1.0]]])
    x = np.array([[1e300, -1e300], [0.0, 0.0]])
    lp = NumpyMixture([1.0], [[0.0, 0.0]], u).log_prob(x)
    assert lp[0] == -np.inf and np.isfinite(lp[1])
    assert GaussianMixture([1.0], [[0.0, 0.0]], u).log_prob(x)[0] == -np.inf
    # a zero-weight component is ignored, not NaN
    gm = NumpyMixture([0.0, 1.0], [[5.0], [0.0]], [[[1.0]], [[1.0]]])
    np.testing.assert_array_equal(gm.log_prob([[0.0]]), [-0.5 * np.log(2 * np.pi)])


def test_sample_over_the_memory_budget_refused_up_front():
    from riskplan.errors import BudgetError
    from riskplan.gaussian_mixture import NumpyMixture

    m = NumpyMixture(np.ones(1), np.zeros((1, 3)), np.eye(3)[None])
    with pytest.raises(BudgetError, match="memory"):
        m.sample(10**12)


def test_covariance_overflow_is_a_named_error():
    """A precision factor of 1e-200 has a covariance beyond float64: a NumericalError, not inf."""
    from riskplan.errors import NumericalError
    from riskplan.gaussian_mixture import NumpyMixture

    m = NumpyMixture(np.ones(1), np.zeros((1, 3)), 1e-200 * np.eye(3)[None])
    for get in (lambda: m.covariance(), lambda: m.covariances):
        with pytest.raises(NumericalError, match="precision"):
            get()
    assert np.isfinite(m.log_prob(np.zeros((1, 3)))).all()
