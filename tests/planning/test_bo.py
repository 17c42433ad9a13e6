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


class Counting:
    """A bound that counts its calls: validation must happen before any evaluation."""

    def __init__(self):
        self.calls = 0

    def __call__(self, c):
        self.calls += 1
        return toy_bound(c)


TOY = np.array([[0.1, 0.1], [0.35, 0.2], [0.9, 0.9]])


@pytest.mark.parametrize(
    "traj, limits, bounds, match",
    [
        (TOY * 10, TOY_LIMITS, None, "trajectory"),  # 10x outside its limits
        (TOY, TOY_LIMITS[:, ::-1], None, "limits"),  # inverted
        (TOY, np.array([[0.0, 1.0], [0.5, 0.5]]), None, "limits"),  # zero span
        (TOY, np.array([[0.0, np.nan], [0.0, 1.0]]), None, "limits"),
        (TOY, TOY_LIMITS[:1], None, "trajectory"),  # limits for another tendon count
        (TOY, TOY_LIMITS, np.array([0.1, 0.2]), "bounds"),  # wrong length
        (TOY, TOY_LIMITS, np.array([0.1, 0.2, 1.5]), "bounds"),  # not a probability
        (TOY, np.zeros(2), None, "limits"),
    ],
)
def test_inputs_checked_before_any_work(traj, limits, bounds, match):
    b = Counting()
    with pytest.raises(InvalidInputError, match=match):
        optimise_trajectory(traj, b, Free(), limits, bounds=bounds)
    assert b.calls == 0


def test_requests_over_the_budget_refused_up_front():
    from riskplan.errors import BudgetError

    b = Counting()
    for cfg, option in (
        (OptimiserConfig(n_candidates=1_000_000_000), "candidates"),
        (OptimiserConfig(iterations=100_000_000), "iterations"),
        (OptimiserConfig(resolution=1e-12), "resolution"),
    ):
        with pytest.raises(BudgetError, match=option):
            optimise_trajectory(TOY, b, Free(), TOY_LIMITS, config=cfg)
    assert b.calls == 0


def _checkpoint(tmp_path, iterations=3):
    ck = tmp_path / "ck.json"
    cfg = OptimiserConfig(iterations=iterations, method="random")
    res = optimise_trajectory(TOY, toy_bound, Free(), TOY_LIMITS, config=cfg, checkpoint=ck)
    return ck, cfg, res


def _resume(ck, cfg):
    return optimise_trajectory(
        TOY, Counting(), Free(), TOY_LIMITS, config=cfg, checkpoint=ck, resume=True
    )


def test_checkpoint_resumes_when_intact(tmp_path):
    ck, cfg, res = _checkpoint(tmp_path)
    again = _resume(ck, cfg)
    np.testing.assert_array_equal(again.trace, res.trace)
    assert "sha256" in json.loads(ck.read_text())


def test_edited_checkpoint_refused(tmp_path):
    """Numbers edited with the fingerprint kept: the content hash refuses them; an edit that
    also recomputes the hash is refused by the range checks."""
    from riskplan.planning.bo import _digest

    ck, cfg, _ = _checkpoint(tmp_path)
    state = json.loads(ck.read_text())
    edited = dict(state, bounds=[0.0] * len(TOY), trace=[0.0] * len(state["trace"]))
    ck.write_text(json.dumps(edited))
    with pytest.raises(DataFormatError, match="content hash"):
        _resume(ck, cfg)
    for key, value in (
        ("bounds", [-0.5, 0.0, 0.0]),  # not a probability
        ("trace", [state["initial_bound"]] + [-0.0] * (len(state["trace"]) - 1)),
        ("iteration", 7),  # more than the run's iterations
        ("trajectory", (TOY * 10).tolist()),  # outside the limits
        ("trajectory", [[0.2, 0.1], *TOY[1:].tolist()]),  # the start moved
        ("evaluations", -3),
        ("accepted", [1, 0, 0]),
    ):
        bad = {k: v for k, v in dict(state, **{key: value}).items() if k != "sha256"}
        bad["sha256"] = _digest(bad)
        ck.write_text(json.dumps(bad))
        with pytest.raises(DataFormatError):
            _resume(ck, cfg)


@pytest.mark.parametrize(
    "content",
    [
        b"[]",
        bytes(range(256)) * 4,  # random bytes, not UTF-8
        b'{"format": "riskplan-trajectory-optimisation"}',
        b"{",
        b"[" * 100_000,  # nested beyond the JSON parser's recursion
    ],
)
def test_bad_resume_files_are_data_format_errors(tmp_path, content):
    ck, cfg, _ = _checkpoint(tmp_path)
    ck.write_bytes(content)
    with pytest.raises(DataFormatError, match="checkpoint"):
        _resume(ck, cfg)


def test_wrong_types_in_a_hashed_checkpoint(tmp_path):
    from riskplan.planning.bo import _digest

    ck, cfg, _ = _checkpoint(tmp_path)
    state = json.loads(ck.read_text())
    for key, value in (
        ("iteration", "3"),
        ("trajectory", "abc"),
        ("X", [[0.1, "x"]]),
        ("p", None),
        ("chosen", [True, -1, -1]),
        ("gp", [1, 2]),
        ("seconds", float("nan")),
    ):
        bad = {k: v for k, v in dict(state, **{key: value}).items() if k != "sha256"}
        try:
            bad["sha256"] = _digest(bad)
        except ValueError:  # NaN cannot be hashed: the hash check refuses it
            bad["sha256"] = state["sha256"]
        ck.write_text(json.dumps(bad))
        with pytest.raises(DataFormatError):
            _resume(ck, cfg)


def test_checkpoint_naming_a_folder_refused_before_work(tmp_path):
    b = Counting()
    with pytest.raises(InvalidInputError, match="folder"):
        optimise_trajectory(TOY, b, Free(), TOY_LIMITS, checkpoint=tmp_path, resume=True)
    assert b.calls == 0
