"""Kinematics fixtures: small synthetic data sets in the data-set HDF5 schema.

Points are drawn from a *known* two-component Gaussian mixture whose weights and
means depend smoothly on the two "tendon displacements" — the oracle for "training
recovers a known mixture". Covariances are constant.
"""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.kinematics.data import write_synthetic_dataset

LOW, HIGH = -0.01, 0.04  # displacement limits [m] (those of the paper's robot)
N_TENDONS = 2
SYNTH_TOML = """# synthetic two-tendon test robot
name = "synthetic"
n_tendons = 2
displacement_limits = [[-0.01, 0.04], [-0.01, 0.04]]
"""
# constant covariances of the two components [m^2]
COV = np.array(
    [
        np.diag([2.0e-3, 1.5e-3, 1.2e-2]) ** 2,
        [[9e-6, 4e-6, 0.0], [4e-6, 9e-6, 0.0], [0.0, 0.0, 4e-5]],
    ]
)


def true_mixture(d: np.ndarray):
    """Weights ``(..., 2)``, means ``(..., 2, 3)``, covariances ``(2, 3, 3)`` at displacements ``(..., 2)``."""
    u = (d - 0.015) / 0.025  # in [-1, 1]
    w1 = 0.25 + 0.5 / (1.0 + np.exp(-1.5 * (u[..., 0] - u[..., 1])))
    weights = np.stack([w1, 1.0 - w1], axis=-1)
    m1 = np.stack([0.03 * u[..., 0], 0.03 * u[..., 1], np.full_like(u[..., 0], 0.05)], axis=-1)
    m2 = np.stack([0.02 * u[..., 1], -0.02 * u[..., 0], 0.14 + 0.01 * u[..., 0]], axis=-1)
    return weights, np.stack([m1, m2], axis=-2), COV


def sample_true(d: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points from the true mixture at each configuration of ``d (C, 2)`` → ``(C, n, 3)``."""
    w, mu, cov = true_mixture(d)
    L = np.linalg.cholesky(cov)
    C = d.shape[0]
    comp = (rng.random((C, n)) > w[:, None, 0]).astype(int)
    z = rng.standard_normal((C, n, 3))
    return mu[np.arange(C)[:, None], comp] + np.einsum("cnij,cnj->cni", L[comp], z)


def make_synthetic(
    path, n_configs: int, seed: int, starts: int = 2, points: int = 256, toml: str = SYNTH_TOML
):
    rng = np.random.default_rng(seed)
    d = rng.uniform(LOW, HIGH, size=(n_configs, N_TENDONS))
    pts = sample_true(d, starts * points, rng).reshape(n_configs, starts, points, 3)
    return write_synthetic_dataset(path, d, pts, robot_toml=toml, robot_name="synthetic", seed=seed)


@pytest.fixture(scope="session")
def synth_paths(tmp_path_factory):
    """(train, test) synthetic data sets: 160 and 40 configurations, 512 points each."""
    root = tmp_path_factory.mktemp("synth")
    return make_synthetic(root / "train.h5", 160, seed=1), make_synthetic(
        root / "test.h5", 40, seed=2
    )


@pytest.fixture(scope="session")
def synth_small(tmp_path_factory):
    """A tiny synthetic data set (24 configurations) for fast plumbing tests."""
    root = tmp_path_factory.mktemp("synth_small")
    return make_synthetic(root / "small.h5", 24, seed=3, starts=1, points=128)


# Small network settings that fit the synthetic mixture in a few seconds.
FAST = dict(hidden=(32, 32), head_hidden=(16,), batch_size=16, lr=5e-3)


@pytest.fixture(scope="session")
def trained(synth_paths, tmp_path_factory):
    """A K=2 model trained on the synthetic training set (float64), saved to a folder."""
    import torch

    from riskplan.kinematics.data import read_point_clouds
    from riskplan.kinematics.training import TrainConfig, train

    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("model")
    cfg = TrainConfig(n_components=2, epochs=30, early_stop_patience=100, dtype="float64", **FAST)
    res = train(read_point_clouds(synth_paths[0]), cfg, out=out)
    return res, out
