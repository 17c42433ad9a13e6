"""Uncertainty cases of paper V-A: documented moments (sample mean/variance within their
confidence intervals), determinism, and that every case drives both scenarios."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import SimParams, actuation_noise, rollout
from riskplan.scenarios.uncertainty import (
    CASE_NAMES,
    ActuationNoise,
    InteractionForceUncertainty,
    MaterialUncertainty,
    MeshUncertainty,
    get_case,
    needle_actuation_cov,
)

N = 4000


def _check_moments(samples, mean, var):
    """Sample mean within 4 standard errors; sample variance within 4 standard errors
    (var of the sample variance ≈ (μ4 − σ⁴)/n, with μ4 estimated from the sample)."""
    x = np.asarray(samples, dtype=float)
    n = len(x)
    assert abs(x.mean() - mean) < 4 * math.sqrt(var / n)
    m4 = np.mean((x - x.mean()) ** 4)
    assert abs(x.var(ddof=1) - var) < 4 * math.sqrt(max(m4 - var**2, 1e-300) / n)


@pytest.mark.parametrize(
    "case,e_var,nu_var", [("material-low", 5.0, 1e-4), ("material-high", 75.0, 4e-4)]
)
def test_material_moments_read_as_variances(case, e_var, nu_var):
    dist = get_case(case)
    draws = dist.sample_many(N, seed=1)
    _check_moments([d.youngs_modulus for d in draws], 50.0, e_var)
    _check_moments([d.poissons_ratio for d in draws], 0.4, nu_var)
    assert dist.variance == (e_var, nu_var) and dist.mean == (50.0, 0.4)
    assert all(
        d.n_elements == 175 and d.force_scale == 1.0 and d.actuation_cov is None for d in draws
    )


def test_mesh_case_uniform_integers():
    dist = get_case("mesh")
    n = np.array([d.n_elements for d in dist.sample_many(N, seed=2)])
    assert n.min() >= 50 and n.max() <= 1000
    _check_moments(n, dist.mean, dist.variance)
    assert dist.mean == 525.0 and dist.planning_params.n_elements == 175


def test_force_case_uniform():
    dist = get_case("force")
    f = np.array([d.force_scale for d in dist.sample_many(N, seed=3)])
    assert f.min() >= 0.0 and f.max() <= 2.0
    _check_moments(f, 1.0, 1.0 / 3.0)


def test_actuation_case_sets_covariance_and_fresh_seeds():
    dist = get_case("actuation")
    draws = dist.sample_many(50, seed=4)
    assert all(d.actuation_cov == needle_actuation_cov() for d in draws)
    assert len({d.actuation_seed for d in draws}) == 50
    # noise pooled over draws and steps has the documented covariance
    w = np.array([actuation_noise(d, t, 2) for d in draws for t in range(80)])
    cov = np.asarray(needle_actuation_cov())
    for k in range(2):
        _check_moments(w[:, k], 0.0, cov[k, k])


def test_nominal_and_determinism():
    nominal = get_case("nominal")
    assert nominal.sample(0) == SimParams() == nominal.planning_params
    for name in CASE_NAMES:
        dist = get_case(name)
        assert dist.sample(123) == dist.sample(123)
        assert dist.sample_many(3, 7) == dist.sample_many(3, 7)
        assert dist.sample_params is not None and dist.name == name


def test_bad_cases():
    with pytest.raises(InvalidInputError, match="case"):
        get_case("bogus")
    with pytest.raises(InvalidInputError):
        MaterialUncertainty(youngs_var=-1.0)
    with pytest.raises(InvalidInputError):
        MeshUncertainty(low=10_000, high=20_000)
    with pytest.raises(InvalidInputError):
        InteractionForceUncertainty(low=-1.0)
    with pytest.raises(InvalidInputError):
        ActuationNoise(cov=(1.0, 2.0))
    with pytest.raises(InvalidInputError):
        get_case("mesh").sample_many(-1)


def test_truncation_keeps_physical_range():
    dist = MaterialUncertainty(youngs_mean=1.0, youngs_var=4.0, poisson_mean=0.45, poisson_var=0.01)
    draws = dist.sample_many(500, seed=5)
    assert all(d.youngs_modulus > 0 and -1 < d.poissons_ratio < 0.5 for d in draws)


@pytest.mark.parametrize("name", CASE_NAMES)
def test_every_case_drives_both_scenarios(name, needle, manip):
    d = get_case(name).sample(11)
    s = rollout(needle, needle.initial_state(d), np.tile([0.4, 0.2], (3, 1)), d)[-1]
    assert np.all(np.isfinite(s.displacement)) and np.all(np.isfinite(s.pose))
    dm = get_case(name, actuation_cov=manip.actuation_cov()).sample(11)
    if name == "mesh":
        dm = dm.replace(n_elements=min(dm.n_elements, 200))  # keep the nonlinear solve cheap
    s = rollout(
        manip, manip.initial_state(dm), np.tile([0.2, 0.2, 0.0, 0.3, -0.2, 0.1], (2, 1)), dm
    )[-1]
    assert np.all(np.isfinite(s.displacement))


def test_with_actuation_adds_noise_to_every_draw():
    """The other reading of the paper's cases: the material draw is unchanged (same
    generator stream first), and each draw carries the actuation covariance and its own
    noise seed; plans still assume no noise."""
    from riskplan.scenarios.uncertainty import WithActuation, get_case, needle_actuation_cov

    inner = get_case("material-high")
    dist = WithActuation(inner=inner)
    a, b = dist.sample(5), inner.sample(5)
    assert a.youngs_modulus == b.youngs_modulus and a.poissons_ratio == b.poissons_ratio
    assert a.actuation_cov == needle_actuation_cov() and b.actuation_cov is None
    draws = dist.sample_many(20, 1)
    assert len({d.actuation_seed for d in draws}) == 20
    assert dist.planning_params == inner.planning_params and dist.name == "material-high+actuation"
    with pytest.raises(InvalidInputError, match="inner"):
        WithActuation(inner="material-high")
