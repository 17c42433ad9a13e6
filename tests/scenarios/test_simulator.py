"""The simulator seam: parameter validation, frozen snapshots, deterministic actuation noise."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import (
    SimParams,
    SimState,
    Simulator,
    actuation_noise,
    apply_actuation_noise,
    check_control,
    rollout,
)


@pytest.mark.parametrize(
    "kw",
    [
        dict(youngs_modulus=0.0),
        dict(youngs_modulus=-3.0),
        dict(youngs_modulus=float("nan")),
        dict(poissons_ratio=0.5),
        dict(poissons_ratio=-1.0),
        dict(poissons_ratio=float("inf")),
        dict(n_elements=3),
        dict(n_elements=175.5),
        dict(n_elements="many"),
        dict(force_scale=-0.1),
        dict(actuation_cov=((1.0, 2.0), (2.0, 1.0))),  # indefinite
        dict(actuation_cov=((1.0, 0.1), (0.0, 1.0))),  # not symmetric
        dict(actuation_cov=(1.0, 2.0)),
    ],
)
def test_params_reject_bad_values(kw):
    with pytest.raises(InvalidInputError):
        SimParams(**kw)


def test_params_are_hashable_values():
    a = SimParams(actuation_cov=np.diag([0.1, 0.2]), actuation_seed=4)
    b = SimParams(actuation_cov=((0.1, 0.0), (0.0, 0.2)), actuation_seed=4)
    assert a == b and hash(a) == hash(b)
    assert a.replace(youngs_modulus=60.0).youngs_modulus == 60.0
    with pytest.raises(InvalidInputError):
        a.replace(youngs_modulus=-1.0)


def test_state_is_frozen_and_read_only():
    d = np.zeros((4, 2))
    s = SimState(t=0, displacement=d, n_elements=10)
    d[0, 0] = 1.0  # the state holds a copy
    assert s.displacement[0, 0] == 0.0
    with pytest.raises(ValueError):
        s.displacement[0, 0] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.t = 3
    assert s.identical(SimState(t=0, displacement=np.zeros((4, 2)), n_elements=10))
    assert not s.identical(SimState(t=0, displacement=np.full((4, 2), 1e-300), n_elements=10))


def test_actuation_noise_is_a_function_of_seed_and_step():
    p = SimParams(actuation_cov=((0.04, 0.01), (0.01, 0.09)), actuation_seed=11)
    w1 = actuation_noise(p, 5, 2)
    assert np.array_equal(w1, actuation_noise(p, 5, 2))
    assert not np.array_equal(w1, actuation_noise(p, 6, 2))
    assert not np.array_equal(w1, actuation_noise(p.replace(actuation_seed=12), 5, 2))
    assert actuation_noise(SimParams(), 5, 2) is None
    with pytest.raises(InvalidInputError):
        actuation_noise(p, 0, 3)


def test_actuation_noise_covariance_matches():
    cov = np.array([[0.04, 0.01], [0.01, 0.09]])
    p = SimParams(actuation_cov=cov, actuation_seed=3)
    n = 4000
    w = np.array([actuation_noise(p, t, 2) for t in range(n)])
    # mean within 4 standard errors, covariance entries within 4 standard errors
    se_mean = np.sqrt(np.diag(cov) / n)
    assert np.all(np.abs(w.mean(0)) < 4 * se_mean)
    emp = np.cov(w.T)
    se_cov = np.sqrt((cov**2 + np.outer(np.diag(cov), np.diag(cov))) / n)
    assert np.all(np.abs(emp - cov) < 4 * se_cov)


def test_noisy_control_is_clipped_to_bounds():
    bounds = np.array([[0.0, 0.5], [-1.0, 1.0]])
    p = SimParams(actuation_cov=((100.0, 0.0), (0.0, 100.0)), actuation_seed=0)
    for t in range(20):
        u = apply_actuation_noise(np.array([0.0, 0.0]), p, t, bounds)
        assert np.all(u >= bounds[:, 0]) and np.all(u <= bounds[:, 1])
    assert np.array_equal(
        apply_actuation_noise(np.array([0.1, 0.2]), SimParams(), 0, bounds), [0.1, 0.2]
    )


@pytest.mark.parametrize(
    "u", [[0.6, 0.0], [-0.01, 0.0], [0.1, 1.5], [np.nan, 0.0], [0.1], [[0.1, 0.1]], "x"]
)
def test_check_control_rejects(u):
    bounds = np.array([[0.0, 0.5], [-1.0, 1.0]])
    with pytest.raises(InvalidInputError, match="control"):
        check_control(u, bounds)


def test_check_control_does_not_alias_input(tol):
    bounds = np.array([[0.0, 0.5], [-1.0, 1.0]])
    u = np.array([0.1, 0.2])
    out = check_control(u, bounds)
    np.testing.assert_allclose(out, u, **tol["float64_exact"])
    assert out is not u


def test_scenarios_satisfy_protocol(needle, manip):
    for sim in (needle, manip):
        assert isinstance(sim, Simulator)
        assert sim.control_bounds.shape == (sim.control_dim, 2)
        x = sim.reduced(sim.initial_state())
        assert x.shape == (sim.state_dim,)
        assert sim.observe(x).shape == (sim.obs_dim,)
        assert sim.observation_matrix.shape == (sim.obs_dim, sim.state_dim)


def test_rollout_returns_all_states(needle):
    u = np.tile([0.3, 0.1], (4, 1))
    states = rollout(needle, needle.initial_state(), u)
    assert [s.t for s in states] == [0, 1, 2, 3, 4]
    with pytest.raises(InvalidInputError):
        rollout(needle, needle.initial_state(), np.zeros((4, 3)))


def test_scenarios_pickle_without_caches(needle, manip):
    """Worker processes receive scenarios by pickling: the copy drops the caches and
    continues a stored state bit-identically."""
    import pickle

    for sim, u in ((needle, [0.4, 0.3]), (manip, [0.3, -0.2, 0.1, 0.2, -0.1, 0.3])):
        s1 = sim.step(sim.initial_state(), u)
        clone = pickle.loads(pickle.dumps(sim))
        assert not clone._models and not clone._meshes
        assert clone.step(s1, u).identical(sim.step(s1, u))
        s2 = pickle.loads(pickle.dumps(s1))
        assert s2.identical(s1) and not s2.displacement.flags.writeable


def test_make_scenario():
    from riskplan.scenarios.registry import make_scenario

    sim = make_scenario("manipulation", "actuation")
    p = sim.sample_params(1)
    assert np.asarray(p.actuation_cov).shape == (6, 6)
    assert make_scenario("needle", "mesh").nominal_params.n_elements == 175
    with pytest.raises(InvalidInputError, match="scenario"):
        make_scenario("liver")
    with pytest.raises(InvalidInputError, match="case"):
        make_scenario("needle", "bogus")


@pytest.mark.parametrize("dim", [2, 3, 24])
def test_gaussian_noise_equals_numpy_multivariate_normal_bit_for_bit(dim):
    """The cached-factor draw is NumPy's ``multivariate_normal(method="cholesky")``: the same
    values bit for bit and the generator left in the same state (executions depend on it)."""
    from riskplan.scenarios.base import gaussian_noise

    a = np.random.default_rng(dim).standard_normal((dim, dim))
    cov = a @ a.T + 0.1 * np.eye(dim)
    for s in range(200):
        g1, g2 = np.random.default_rng(s), np.random.default_rng(s)
        ref = g1.multivariate_normal(np.zeros(dim), cov, method="cholesky")
        got = gaussian_noise(cov, None, g2, dim)
        assert got.shape == (dim,) and got.tobytes() == ref.tobytes()
        assert g1.random() == g2.random()


def test_unpickled_copies_share_meshes_and_models(monkeypatch):
    """Copies of one scenario unpickled in a process (the tasks of a worker) share its FEM
    caches, and results are those of a fresh scenario bit for bit."""
    import pickle

    from riskplan.scenarios import base
    from riskplan.scenarios.registry import make_scenario

    monkeypatch.setattr(base, "_SHARED_CACHES", {})  # this test's copies only

    sim = make_scenario("needle", "material-high")
    a, b = pickle.loads(pickle.dumps(sim)), pickle.loads(pickle.dumps(sim))
    assert a._models is b._models and a._meshes is b._meshes
    params = sim.distribution.sample(0)
    u = np.array([0.8 * sim.config.v_max, 0.1])
    ya = a.step(a.initial_state(params), u, params)
    assert params.material_key in b._models  # built by a, found by b
    yb = b.step(b.initial_state(params), u, params)
    fresh = make_scenario("needle", "material-high")
    yf = fresh.step(fresh.initial_state(params), u, params)
    for y in (ya, yb):
        assert y.displacement.tobytes() == yf.displacement.tobytes()
        assert np.asarray(y.pose).tobytes() == np.asarray(yf.pose).tobytes()
    # another configuration does not share
    other = pickle.loads(pickle.dumps(make_scenario("manipulation", "material-high")))
    assert other._models is not a._models
