import numpy as np
import pytest
import torch
from scipy.stats import multivariate_normal

from riskplan.errors import InvalidInputError
from riskplan.kinematics import GaussianMixture
from tests.conftest import TOL


def _random_mixture(rng, batch=(), K=4, d=3):
    A = rng.normal(size=batch + (K, d, d))
    cov = A @ np.swapaxes(A, -1, -2) + 0.3 * np.eye(d)
    w = rng.dirichlet(np.ones(K), size=batch) if batch else rng.dirichlet(np.ones(K))
    mu = rng.normal(size=batch + (K, d))
    return w, mu, cov


def _scipy_logpdf(w, mu, cov, x):
    dens = sum(w[k] * multivariate_normal(mu[k], cov[k]).pdf(x) for k in range(len(w)))
    return np.log(dens)


@pytest.mark.parametrize("d", [1, 2, 3])
def test_log_prob_matches_scipy(rng, tol, d):
    w, mu, cov = _random_mixture(rng, K=4, d=d)
    gm = GaussianMixture.from_covariances(w, mu, cov)
    x = rng.normal(size=(11, d)) * 2
    np.testing.assert_allclose(
        gm.log_prob(x).numpy(), _scipy_logpdf(w, mu, cov, x), **tol["float64_ref"]
    )
    np.testing.assert_allclose(gm.covariances.numpy(), cov, **tol["float64_ref"])


def test_batch_equals_loop(rng, tol):
    w, mu, cov = _random_mixture(rng, batch=(2, 3))
    gm = GaussianMixture.from_covariances(w, mu, cov)
    x = rng.normal(size=(2, 3, 5, 3))
    batched = gm.log_prob(x).numpy()
    for i in range(2):
        for j in range(3):
            np.testing.assert_allclose(
                gm[i, j].log_prob(x[i, j]).numpy(), batched[i, j], **tol["float64_exact"]
            )


def test_far_points_are_finite_and_gradients_finite(rng):
    w, mu, cov = _random_mixture(rng)
    gm = GaussianMixture.from_covariances(w, mu, cov)
    x = torch.tensor([[1e4, -1e4, 1e4]], dtype=torch.float64, requires_grad=True)
    lp = gm.log_prob(x)
    assert torch.isfinite(lp).all()
    lp.sum().backward()
    assert torch.isfinite(x.grad).all()


def test_sample_moments(rng):
    w, mu, cov = _random_mixture(rng, K=2)
    gm = GaussianMixture.from_covariances(w, mu, cov)
    s = gm.sample(400_000, seed=5).numpy()
    mean = (w[:, None] * mu).sum(0)
    second = sum(w[k] * (cov[k] + np.outer(mu[k], mu[k])) for k in range(2))
    full_cov = second - np.outer(mean, mean)
    se = np.sqrt(np.diag(full_cov) / len(s))
    assert np.all(np.abs(s.mean(0) - mean) < 5 * se)
    np.testing.assert_allclose(np.cov(s.T), full_cov, **TOL["monte_carlo_cov"])


def test_sample_seeded_and_batched(rng):
    w, mu, cov = _random_mixture(rng, batch=(4,))
    gm = GaussianMixture.from_covariances(w, mu, cov)
    a, b = gm.sample(10, seed=3), gm.sample(10, seed=3)
    assert a.shape == (4, 10, 3)
    torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_float32_close_to_float64(rng, tol):
    w, mu, cov = _random_mixture(rng)
    gm = GaussianMixture.from_covariances(w, mu, cov)
    x = rng.normal(size=(9, 3))
    lp32 = gm.to(torch.float32).log_prob(torch.as_tensor(x, dtype=torch.float32))
    assert lp32.dtype == torch.float32
    np.testing.assert_allclose(lp32.double().numpy(), gm.log_prob(x).numpy(), **tol["float32_ref"])


def test_numpy_round_trip(rng, tol):
    w, mu, cov = _random_mixture(rng)
    gm = GaussianMixture.from_covariances(w, mu, cov)
    back = GaussianMixture.from_numpy(**gm.numpy())
    x = rng.normal(size=(4, 3))
    np.testing.assert_allclose(
        back.log_prob(x).numpy(), gm.log_prob(x).numpy(), **tol["float64_exact"]
    )


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda w, m, u: (w * 2, m, u), "sum to 1"),
        (lambda w, m, u: (w, m[..., :2], u), "precision_cholesky"),
        (lambda w, m, u: (w, m, np.swapaxes(u, -1, -2)), "upper triangular"),
        (lambda w, m, u: (w, m, -u), "positive"),
        (lambda w, m, u: (w, m * np.nan, u), "NaN"),
        (lambda w, m, u: (w[..., :2], m, u), "weights"),
    ],
)
def test_invalid(rng, mutate, match):
    w, mu, cov = _random_mixture(rng)
    gm = GaussianMixture.from_covariances(w, mu, cov)
    p = gm.numpy()
    args = mutate(p["weights"], p["means"], p["precision_cholesky"])
    with pytest.raises(InvalidInputError, match=match):
        GaussianMixture(*args)


def test_non_pd_covariance_rejected():
    cov = np.array([[[1.0, 2.0], [2.0, 1.0]]])
    with pytest.raises(InvalidInputError, match="positive definite"):
        GaussianMixture.from_covariances([1.0], [[0.0, 0.0]], cov)


@pytest.mark.parametrize(
    "points, match",
    [
        (np.full((2, 3), np.nan), "NaN"),
        (np.array([[0.0, np.inf, 0.0]]), "NaN or inf"),
        (np.zeros(3), r"\(\.\.\., N, 3\)"),  # a single point without the N axis
        (np.zeros((4, 2)), r"\(\.\.\., N, 3\)"),  # wrong dimension
        (1.0, r"\(\.\.\., N, 3\)"),
        (None, "numeric"),
        ("0,0,0", "numeric"),
        (np.zeros((2, 3), dtype=complex), "numeric"),
        (np.zeros((5, 4, 3)), "broadcast"),  # leading axis 5 against batch shape (2,)
    ],
)
def test_log_prob_rejects_bad_points(rng, points, match):
    w, mu, cov = _random_mixture(rng, batch=(2,))
    gm = GaussianMixture.from_covariances(w, mu, cov)
    with pytest.raises(InvalidInputError, match=match):
        gm.log_prob(points)


def test_log_prob_overflowing_quadratic_form_is_minus_inf_not_nan():
    # U (x - mu) overflows with opposite signs (inf - inf): the density is 0, log density -inf
    u = np.array([[[1e300, 1e300], [0.0, 1.0]]])
    gm = GaussianMixture([1.0], [[0.0, 0.0]], u)
    lp = gm.log_prob(np.array([[1e300, -1e300], [0.0, 0.0]]))
    assert lp[0] == -np.inf and np.isfinite(lp[1])


@pytest.mark.parametrize("seed", [-1, 1.5, "x", True])
def test_sample_bad_seed_is_named(seed):
    # a negative seed used to reach NumPy's SeedSequence ValueError
    gm = GaussianMixture([1.0], [[0.0, 0.0, 0.0]], np.eye(3)[None])
    with pytest.raises(InvalidInputError, match="seed"):
        gm.sample(2, seed=seed)
