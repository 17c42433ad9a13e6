import numpy as np
import pytest
import torch
from scipy.stats import multivariate_normal

from riskplan.errors import InvalidInputError
from riskplan.kinematics import GaussianMixture
from riskplan.kinematics.mdn import (
    LOG_DIAG_BOUND,
    MDN,
    MDNModel,
    Normalisation,
    build_precision_cholesky,
    mixture_log_prob,
)
from tests.conftest import TOL

LIMITS = np.array([[-0.01, 0.04]] * 4)


def _model(rng, dtype=torch.float64, K=3, activation="silu"):
    torch.manual_seed(int(rng.integers(1 << 30)))
    net = MDN(4, K, hidden=(16, 16), head_hidden=(8,), activation=activation).to(dtype)
    with torch.no_grad():
        for p in net.parameters():
            p.normal_(0.0, 0.4)
    norm = Normalisation(
        np.full(4, 0.015),
        np.full(4, 0.014),
        np.array([0.0, 0.0, 0.1]),
        np.array([0.01, 0.02, 0.05]),
    )
    return MDNModel(net, norm, LIMITS, "", "test")


def test_precision_cholesky_is_eq2(rng, tol):
    raw = torch.as_tensor(rng.normal(size=(5, 2, 6)))
    u = build_precision_cholesky(raw, 3).numpy()
    r = raw.numpy()
    expected = np.zeros((5, 2, 3, 3))
    # row-wise upper triangle: (0,0) (0,1) (0,2) (1,1) (1,2) (2,2)
    for n, (i, j) in enumerate([(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]):
        expected[..., i, j] = np.exp(r[..., n]) if i == j else r[..., n]
    np.testing.assert_allclose(u, expected, **tol["float64_exact"])


def test_mixture_log_prob_matches_scipy(rng, tol):
    K = 3
    A = rng.normal(size=(K, 3, 3))
    cov = A @ np.swapaxes(A, -1, -2) + 0.2 * np.eye(3)
    w = rng.dirichlet(np.ones(K))
    mu = rng.normal(size=(K, 3))
    gm = GaussianMixture.from_covariances(w, mu, cov)
    x = rng.normal(size=(9, 3))
    got = mixture_log_prob(
        torch.log(gm.weights), gm.means, gm.precision_cholesky, torch.as_tensor(x)
    ).numpy()
    ref = np.log(sum(w[k] * multivariate_normal(mu[k], cov[k]).pdf(x) for k in range(K)))
    np.testing.assert_allclose(got, ref, **tol["float64_ref"])


def test_numpy_fast_path_equals_torch(rng, tol):
    for act in ("silu", "tanh", "relu"):
        m = _model(rng, activation=act)
        d = rng.uniform(-0.01, 0.04, size=(7, 4))
        fast = m.predict(d)
        ref = m.mixture(torch.as_tensor(d))
        for name in ("weights", "means", "precision_cholesky"):
            a, b = getattr(fast, name).numpy(), getattr(ref, name).detach().numpy()
            np.testing.assert_allclose(
                a,
                b,
                rtol=tol["numpy_vs_torch"]["rtol"],
                atol=tol["numpy_vs_torch"]["atol"] * np.abs(b).max(),
            )
        fast.validate()


def test_numpy_fast_path_float32_network(rng, tol):
    m = _model(rng)
    m32 = MDNModel(m.net.float(), m.normalisation, LIMITS)
    d = rng.uniform(-0.01, 0.04, size=(6, 4))
    fast = m32.predict(d)
    ref = m32.mixture(torch.as_tensor(d, dtype=torch.float32))
    assert fast.dtype == torch.float64
    np.testing.assert_allclose(
        fast.weights.numpy(), ref.weights.detach().numpy(), **tol["float32_ref"]
    )
    np.testing.assert_allclose(
        fast.means.numpy(), ref.means.detach().numpy(), **tol["float32_means"]
    )
    u_ref = ref.precision_cholesky.detach().numpy()
    np.testing.assert_allclose(
        fast.precision_cholesky.numpy(),
        u_ref,
        rtol=tol["float32_scaled"]["rtol"],
        atol=tol["float32_scaled"]["atol"] * np.abs(u_ref).max(),
    )


def test_predict_batch_equals_loop(rng, tol):
    m = _model(rng)
    d = rng.uniform(-0.01, 0.04, size=(2, 3, 4))
    batched = m.predict(d)
    assert batched.batch_shape == (2, 3)
    for i in range(2):
        for j in range(3):
            one = m.predict(d[i, j])
            assert one.batch_shape == ()
            for name in ("weights", "means", "precision_cholesky"):
                np.testing.assert_allclose(
                    getattr(one, name).numpy(),
                    getattr(batched, name).numpy()[i, j],
                    **tol["float64_exact"],
                )


def test_large_batch_equals_loop(rng):
    """From 256 rows on the SiLU uses another (faster) formula; results agree to rounding."""
    m = _model(rng)
    d = rng.uniform(-0.01, 0.04, size=(300, 4))
    big = m.predict(d)
    for i in (0, 137, 299):
        one = m.predict(d[i])
        for name in ("weights", "means", "precision_cholesky"):
            np.testing.assert_allclose(
                getattr(big, name).numpy()[i],
                getattr(one, name).numpy(),
                **TOL["float64_exact_small"],
            )


def test_predict_float32_and_float64(rng, tol):
    m = _model(rng)
    d = rng.uniform(-0.01, 0.04, size=(5, 4))
    g64 = m.predict(d)
    g32 = m.predict(d, dtype=torch.float32)
    assert g64.dtype == torch.float64 and g32.dtype == torch.float32
    x = g64.sample(16, seed=1)
    np.testing.assert_allclose(
        g32.log_prob(x.float()).numpy(), g64.log_prob(x).numpy(), **tol["float32_log_density"]
    )
    # the torch module in float32 agrees with float64
    m32 = MDNModel(m.net.float(), m.normalisation, LIMITS)
    g = m32.mixture(torch.as_tensor(d, dtype=torch.float32))
    np.testing.assert_allclose(g.means.detach().numpy(), g64.means.numpy(), **tol["float32_ref"])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_gradients_finite_at_extreme_inputs(rng, dtype):
    m = _model(rng, dtype=dtype)
    corners = np.array(np.meshgrid(*[[-0.01, 0.04]] * 4)).reshape(4, -1).T
    extreme = np.concatenate(
        [corners, [[1e3, -1e3, 1e3, -1e3], [-1e4] * 4]]
    )  # far outside: network only
    d = torch.as_tensor(extreme, dtype=dtype)
    pts = torch.as_tensor(rng.normal(size=(len(extreme), 20, 3)) * 0.1, dtype=dtype)
    pts[0, 0] = torch.tensor([1e3, -1e3, 1e3])  # a far point
    m.net.zero_grad()
    log_w, mu, u = m.net((d - 0.015) / 0.014)
    loss = -mixture_log_prob(log_w, mu, u, pts).mean()
    assert torch.isfinite(loss)
    loss.backward()
    for p in m.net.parameters():
        assert torch.isfinite(p.grad).all()
    diag = torch.diagonal(u, dim1=-2, dim2=-1)
    assert (diag <= np.exp(LOG_DIAG_BOUND) * 1.0001).all() and (diag > 0).all()


def test_predict_rejects_bad_input(rng):
    m = _model(rng)
    with pytest.raises(InvalidInputError, match="last dimension 4"):
        m.predict(np.zeros(3))
    with pytest.raises(InvalidInputError, match="NaN or inf"):
        m.predict([0.0, np.nan, 0.0, 0.0])
    with pytest.raises(InvalidInputError, match="NaN or inf"):
        m.predict([0.0, 0.0, np.inf, 0.0])
    with pytest.raises(InvalidInputError, match="limits"):
        m.predict([0.0, 0.05, 0.0, 0.0])
    with pytest.raises(InvalidInputError, match="limits"):
        m.predict([[0.0] * 4, [-0.02, 0.0, 0.0, 0.0]])
    m.predict([0.04, -0.01, 0.0, 0.04])  # limits are inclusive


def test_mdn_rejects_bad_architecture():
    with pytest.raises(InvalidInputError):
        MDN(4, 0)
    with pytest.raises(InvalidInputError):
        MDN(4, 3, activation="sigmoid")
    with pytest.raises(InvalidInputError):
        MDN(4, 3, hidden=())
