"""Path dependence: play operator, approach direction, retracing, run-to-run variation."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.robots import load_robot
from riskplan.robots.hysteresis import (
    HysteresisModel,
    HysteresisState,
    effective_displacements,
    play_operator,
    robot_after_path,
)
from tests.conftest import TOL


@pytest.fixture(scope="module")
def paper():
    return load_robot("paper")


def test_play_operator_band(rng):
    b = 0.3
    c = np.cumsum(rng.normal(size=(200, 1)), 0)
    e = np.zeros(1)
    for t in range(200):
        e = play_operator(e, c[t : t + 1], b)
        assert abs(e[0] - c[t, 0]) <= b + TOL["round_off"]["atol"]
    # monotone rise then fall: lag below on the way up, above on the way down
    assert play_operator(0.0, np.array([[1.0], [2.0]]), b)[0] == pytest.approx(2.0 - b)
    assert play_operator(3.0, np.array([[2.5], [2.0]]), b)[0] == pytest.approx(2.0 + b)


def test_approach_from_above_and_below_differ(paper):
    target = np.array([0.015, 0.0, 0.005, 0.0])
    below = robot_after_path(paper, [[0.0, 0, 0, 0], target])
    above = robot_after_path(paper, [[0.03, 0.01, 0.02, 0.01], target])
    gap = np.linalg.norm(below.tip - above.tip)
    assert gap > 1e-3  # millimetres apart


def test_retracing_the_same_path_gives_the_same_shape(paper):
    model = HysteresisModel(paper)
    path = np.array([[0.0, 0, 0, 0], [0.02, 0.0, 0.01, 0.0], [0.01, 0.005, 0.0, 0.002]])
    state0 = model.initial_state()
    _s1, shape1 = model.shape_after(state0, path)
    _s2, shape2 = model.shape_after(state0, path)
    np.testing.assert_array_equal(shape1.positions, shape2.positions)
    # a closed loop back to the loop's start from the end state lands on the same state as the first visit
    loop = np.concatenate([path, path[::-1][1:], path[1:]])
    _s3, shape3 = model.shape_after(state0, loop)
    np.testing.assert_allclose(shape3.positions, shape1.positions, **TOL["float64_exact"])


def test_straight_line_equals_densely_sampled_path(paper, rng):
    model = HysteresisModel(paper)
    starts = rng.uniform(-0.01, 0.04, (10, 4))
    targets = rng.uniform(-0.01, 0.04, (10, 4))
    _, eff = model.straight_line(starts, targets)
    t = np.linspace(0, 1, 50)[:, None]
    for i in range(10):
        path = starts[i] + t * (targets[i] - starts[i])
        _, e = model.move(model.initial_state(starts[i]), path)
        np.testing.assert_allclose(eff[i], e, **TOL["float64_exact"])


def test_run_to_run_variation_is_seeded(paper):
    path = [[0.03, 0.0, 0.0, 0.0], [0.01, 0.0, 0.0, 0.0]]
    a = effective_displacements(paper, path, seed=7)
    b = effective_displacements(paper, path, seed=7)
    c = effective_displacements(paper, path, seed=8)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0
    nominal = effective_displacements(paper, path)
    np.testing.assert_allclose(
        nominal, [0.01 + paper.params.hysteresis.play, 0, 0, 0], **TOL["float64_exact"]
    )


def test_tip_spread_is_millimetres(paper):
    """Same target from random starts: the spread is a few millimetres (docs/robots.md)."""
    model = HysteresisModel(paper)
    rng = np.random.default_rng(3)
    target = np.array([0.01, 0.0, 0.0, 0.0])
    starts = rng.uniform(-0.01, 0.04, (64, 4))
    _, eff = model.straight_line(starts, np.broadcast_to(target, starts.shape), rng)
    tips = paper.solve_displacements(eff).tip
    rms = np.sqrt(((tips - tips.mean(0)) ** 2).sum(-1).mean())
    assert 1e-3 < rms < 1e-2


def test_bad_input(paper):
    model = HysteresisModel(paper)
    with pytest.raises(InvalidInputError, match="path"):
        model.move(model.initial_state(), [[0.05, 0, 0, 0]])
    with pytest.raises(InvalidInputError, match="path"):
        model.move(model.initial_state(), [0.0, 0, 0, 0])
    with pytest.raises(InvalidInputError, match="path"):
        model.move(model.initial_state(), [[np.nan, 0, 0, 0]])


@pytest.mark.parametrize(
    "engaged, fragment",
    [
        (np.full(4, np.nan), "NaN"),  # used to give NaN outputs silently
        (np.array([0.02]), "last dimension 4"),  # used to broadcast across the tendons
        (np.zeros(3), "last dimension 4"),  # used to raise a raw numpy ValueError
        (np.zeros((3, 4)), "broadcast"),  # batch (3,) against a path batch (2,)
        ("abc", "cannot convert"),
    ],
)
def test_state_engaged_is_validated(paper, engaged, fragment):
    model = HysteresisModel(paper)
    path = np.zeros((2, 2, 4))
    with pytest.raises(InvalidInputError, match=f"state.engaged.*{fragment}"):
        model.move(HysteresisState(engaged), path)
    with pytest.raises(InvalidInputError, match=r"state.engaged"):
        effective_displacements(paper, path, state=HysteresisState(engaged))
    with pytest.raises(InvalidInputError, match="state"):
        model.move(np.zeros(4), path)


def test_start_state_of_straight_line_is_validated(paper):
    model = HysteresisModel(paper)
    with pytest.raises(InvalidInputError, match=r"state.engaged"):
        model.straight_line(
            np.zeros(4), np.full(4, 0.01), start_state=HysteresisState(np.array([np.inf, 0, 0, 0]))
        )


@pytest.mark.parametrize("shape", [(0, 4), (3, 0, 4)])
def test_empty_path_is_a_clean_error(paper, shape):
    with pytest.raises(InvalidInputError, match="path: expected at least one configuration"):
        effective_displacements(paper, np.zeros(shape))
    with pytest.raises(InvalidInputError, match="path: expected at least one configuration"):
        robot_after_path(paper, np.zeros(shape))


def test_move_along_empty_path_returns_a_new_state(paper):
    model = HysteresisModel(paper)
    state = model.initial_state([0.01, 0, 0, 0])
    new, eff = model.move(state, np.zeros((0, 4)))
    np.testing.assert_array_equal(new.engaged, state.engaged)
    np.testing.assert_array_equal(eff, state.engaged)
    assert not np.shares_memory(new.engaged, state.engaged)
