import numpy as np
import pytest
import torch
from scipy.stats import chi2

from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.kinematics import GaussianMixture
from riskplan.kinematics.data import read_point_clouds
from riskplan.kinematics.evaluation import (
    chamfer_distance,
    evaluate,
    hdr_coverage,
    hdr_thresholds,
    mode_collapse,
    nll_per_config,
)
from tests.conftest import TOL


def test_chamfer_matches_brute_force(rng, tol):
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(70, 3)) + 0.3
    dist = np.linalg.norm(a[:, None] - b[None], axis=-1)
    ref = 0.5 * (dist.min(1).mean() + dist.min(0).mean())
    np.testing.assert_allclose(chamfer_distance(a, b), ref, **tol["float64_ref"])
    assert chamfer_distance(a, a) == 0.0
    with pytest.raises(InvalidInputError):
        chamfer_distance(a, np.zeros((0, 3)))


def test_hdr_threshold_single_gaussian_closed_form(rng):
    """For one Gaussian the level-a HDR is the Mahalanobis ball r^2 <= chi2_3(a)."""
    A = rng.normal(size=(3, 3))
    cov = A @ A.T + 0.5 * np.eye(3)
    gm = GaussianMixture.from_covariances([1.0], rng.normal(size=(1, 3)), cov[None])
    levels = (0.5, 0.9, 0.95)
    thr = hdr_thresholds(gm, levels, n_samples=200_000, seed=1).numpy()
    logdet = np.log(np.linalg.det(cov))
    exact = -1.5 * np.log(2 * np.pi) - 0.5 * logdet - 0.5 * chi2.ppf(levels, df=3)
    # quantile of 2e5 samples: sd of the level estimate ~ sqrt(a(1-a)/n) < 1.2e-3; in log density
    # that is ~ f'(q) shifts of a few 1e-3 nats
    np.testing.assert_allclose(thr, exact, **TOL["hdr_threshold"])


def test_hdr_coverage_of_own_samples_is_nominal(rng):
    """Points drawn from the mixture itself fall in its level-a HDR with probability a."""
    A = rng.normal(size=(6, 3, 3)) * 0.3
    cov = A @ np.swapaxes(A, -1, -2) + 0.05 * np.eye(3)
    gm = GaussianMixture.from_covariances(
        rng.dirichlet(np.ones(3), size=2), rng.normal(size=(2, 3, 3)), cov.reshape(2, 3, 3, 3)
    )
    pts = gm.sample(20_000, seed=7)
    cov_hat = hdr_coverage(gm, pts, (0.5, 0.9, 0.95), n_samples=20_000, seed=8).numpy()
    # two independent estimates of the same quantile: sd of the difference ~ sqrt(2 a(1-a)/n) <= 7.1e-3
    np.testing.assert_allclose(
        cov_hat, np.broadcast_to([0.5, 0.9, 0.95], (2, 3)), **TOL["hdr_coverage"]
    )


def test_evaluate_on_synthetic(trained, synth_paths):
    res, _ = trained
    test = read_point_clouds(synth_paths[1])
    ev = evaluate(res.model, test, n_samples=4096, seed=0)
    assert ev.n_configs == test.n_configs
    np.testing.assert_allclose(
        ev.nll, nll_per_config(res.model, test).mean(), **TOL["float64_exact_rel"]
    )
    # the model is close to the truth, so it is calibrated (sampling error ~0.01 per level)
    for a, c in ev.calibration.items():
        assert abs(c - a) < 0.05, (a, c)
    # Chamfer between two samples of the same distribution is a few mm at 512 points
    assert 0 < ev.chamfer < 5e-3
    assert set(ev.to_json()) >= {"test_nll", "chamfer_m", "calibration"}


def test_nll_per_config_matches_direct(trained, synth_paths, tol):
    res, _ = trained
    test = read_point_clouds(synth_paths[1])
    got = nll_per_config(res.model, test)
    gm = res.model.predict(test.displacements[3])
    ref = -gm.log_prob(torch.from_numpy(test.points[3].astype(np.float64))).mean().item()
    np.testing.assert_allclose(got[3], ref, **tol["float64_ref"])


def test_evaluate_other_robot_rejected(trained, tmp_path):
    from tests.kinematics.conftest import make_synthetic

    res, _ = trained
    other = read_point_clouds(
        make_synthetic(tmp_path / "o.h5", 4, seed=0, starts=1, points=8, toml='name = "x"\n')
    )
    with pytest.raises(DataFormatError, match="differs"):
        evaluate(res.model, other)


def test_mode_collapse():
    assert mode_collapse(np.array([0.5, 0.005, 0.3, 0.0]), 0.01) == [1, 3]
    assert mode_collapse(np.array([0.5, 0.5]), 0.01) == []
    with pytest.raises(InvalidInputError):
        mode_collapse(np.array([0.5]), 1.5)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"max_configs": -1}, "max_configs"),
        ({"max_configs": 0}, "max_configs"),
        ({"chamfer_points": 0}, "chamfer_points"),
        ({"n_samples": -5}, "n_samples"),
        ({"seed": -1}, "seed"),
    ],
)
def test_evaluate_bad_counts_are_named(trained, synth_small, kwargs, name):
    # max_configs=-1 used to reach NumPy's "negative dimensions" ValueError
    res, _ = trained
    with pytest.raises(InvalidInputError, match=name):
        evaluate(res.model, read_point_clouds(synth_small), **kwargs)
