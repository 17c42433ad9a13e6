"""The paper's Bayesian optimisation and the comparison optimisers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from riskplan.collision import trajectory_bound
from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.planning.bo import OptimiserConfig, optimise_trajectory
from riskplan.planning.prm import MeanValidity, build_roadmap, interpolate_path
from riskplan.planning.risk import ConfigurationBound
from tests.planning.conftest import GOAL, LIMITS, START

TOY_LIMITS = np.array([[0.0, 1.0], [0.0, 1.0]])
OPTIMUM = np.array([0.62, 0.41])


class Free:
    """Everything valid (toy problem)."""

    def __call__(self, c):
        return np.ones(len(np.atleast_2d(c)), dtype=bool)

    def motions(self, a, b, resolution):
        return np.ones(len(np.atleast_2d(a)), dtype=bool)


def toy_bound(c):
    """A smooth per-configuration 'bound' with its minimum 0.01 at OPTIMUM."""
    c = np.atleast_2d(c)
    return 0.01 + 0.4 * (1 - np.exp(-np.sum((c - OPTIMUM) ** 2, axis=-1) / 0.05))


def test_bo_finds_known_optimum():
    traj = np.array([[0.1, 0.1], [0.35, 0.2], [0.9, 0.9]])  # the middle one is free to move
    cfg = OptimiserConfig(iterations=20, n_candidates=256, radius=0.1)
    res = optimise_trajectory(traj, toy_bound, Free(), TOY_LIMITS, config=cfg, seed=0)
    best = 1 - (1 - toy_bound(traj[[0]])[0]) * (1 - 0.01) * (1 - toy_bound(traj[[2]])[0])
    assert np.linalg.norm(res.trajectory[1] - OPTIMUM) < 0.03
    assert res.bound - best < 2e-3
    np.testing.assert_array_equal(res.trajectory[[0, 2]], traj[[0, 2]])
    assert res.evaluations == 3 + 20


@pytest.fixture(scope="module")
def problem(model, scene):
    v = MeanValidity(model, scene)
    rm = build_roadmap(v, n_milestones=50, seed=2)
    traj = interpolate_path(rm.shortest_path(START, GOAL), 0.004)
    return v, ConfigurationBound(model, scene), traj


def test_bo_never_worse_and_valid(problem, model, scene, tol):
    v, bound, traj = problem
    for method in ("bo", "random", "trust_region"):
        res = optimise_trajectory(
            traj, bound, v, LIMITS, config=OptimiserConfig(iterations=6, method=method), seed=1
        )
        assert res.bound <= res.initial_bound
        assert np.all(np.diff(res.trace) <= 0)
        np.testing.assert_array_equal(res.trajectory[[0, -1]], traj[[0, -1]])
        out = res.trajectory
        assert np.all((out >= LIMITS[:, 0]) & (out <= LIMITS[:, 1]))
        assert v(out).all() and v.motions(out[:-1], out[1:], 0.001).all()
        # the reported bound is eq. 10 of the returned trajectory, recomputed from scratch
        np.testing.assert_allclose(
            res.bound, trajectory_bound(model.predict(out), scene), **tol["float64_ref"]
        )
        assert res.evaluations == len(traj) + 6 - sum(c < 0 for c in res.chosen)


def test_same_seed_same_result_and_resume(problem, tmp_path):
    v, bound, traj = problem
    cfg = OptimiserConfig(iterations=4)
    a = optimise_trajectory(traj, bound, v, LIMITS, config=cfg, seed=7)
    assert a.accepted.any()
    short = tmp_path / "short.json"

    def interrupt(i, n, b):  # an interruption after the second completed iteration
        if i == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        optimise_trajectory(
            traj, bound, v, LIMITS, config=cfg, seed=7, checkpoint=short, progress=interrupt
        )
    assert json.loads(short.read_text())["iteration"] == 2
    r = optimise_trajectory(
        traj, bound, v, LIMITS, config=cfg, seed=7, checkpoint=short, resume=True
    )
    # same seed, same result, also across an interruption
    np.testing.assert_array_equal(r.trajectory, a.trajectory)
    np.testing.assert_array_equal(r.trace, a.trace)
    with pytest.raises(DataFormatError, match="another trajectory, seed or settings"):
        optimise_trajectory(
            traj, bound, v, LIMITS, config=cfg, seed=8, checkpoint=short, resume=True
        )


def test_options_checked(problem):
    v, bound, traj = problem
    with pytest.raises(InvalidInputError, match="radius"):
        optimise_trajectory(traj, bound, v, LIMITS, config=OptimiserConfig(radius=float("inf")))
    with pytest.raises(InvalidInputError, match="method"):
        optimise_trajectory(traj, bound, v, LIMITS, config=OptimiserConfig(method="sgd"))
    with pytest.raises(InvalidInputError, match="trajectory"):
        optimise_trajectory(traj[:, :1], bound, v, LIMITS)
