"""PRM in displacement space: validity of everything returned, determinism, named errors."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.errors import InvalidInputError, PlanningError
from riskplan.planning.prm import (
    MeanValidity,
    build_roadmap,
    goal_from_tip,
    interpolate_path,
    segment_owners,
    tip_positions,
)
from tests.conftest import TOL
from tests.planning.conftest import GOAL, LIMITS, START


@pytest.fixture(scope="module")
def roadmap(model, scene):
    return build_roadmap(MeanValidity(model, scene), n_milestones=60, seed=3)


def _means_free(model, env, configs):
    mu = model.predict(configs).means.numpy()
    return ~env.contains(mu.reshape(-1, 3)).reshape(mu.shape[:2]).any(-1)


def test_roadmap_vertices_and_edges_valid(roadmap, model, scene):
    assert roadmap.n_milestones == 60 and 55 <= roadmap.n_vertices <= 60 and roadmap.n_edges > 60
    assert np.all((roadmap.vertices >= LIMITS[:, 0]) & (roadmap.vertices <= LIMITS[:, 1]))
    assert _means_free(model, scene, roadmap.vertices).all()
    # every edge is a valid motion at the stated resolution (independent re-check, one motion at a time)
    v = roadmap.validity
    for a, b in roadmap.edges[:40]:
        n = (
            int(
                np.ceil(
                    np.linalg.norm(roadmap.vertices[b] - roadmap.vertices[a]) / roadmap.resolution
                )
            )
            + 1
        )
        pts = np.linspace(roadmap.vertices[a], roadmap.vertices[b], n)
        assert _means_free(model, scene, pts).all()
    assert v.motions(
        roadmap.vertices[roadmap.edges[:, 0]], roadmap.vertices[roadmap.edges[:, 1]]
    ).all()


def test_motions_batch_equals_loop(model, scene, rng):
    v = MeanValidity(model, scene)
    a = LIMITS[:, 0] + rng.random((30, 2)) * 0.05
    b = LIMITS[:, 0] + rng.random((30, 2)) * 0.05
    batch = v.motions(a, b, 0.002)
    loop = [v.motions(a[i : i + 1], b[i : i + 1], 0.002)[0] for i in range(30)]
    assert batch.tolist() == loop
    assert 0 < batch.sum() < 30  # the scene blocks some motions and not others


def test_trajectory_valid_and_spaced(roadmap, model, scene):
    path = roadmap.shortest_path(START, GOAL)
    traj = interpolate_path(path, 0.0025)
    np.testing.assert_array_equal(traj[0], START)
    np.testing.assert_array_equal(traj[-1], GOAL)
    assert np.all((traj >= LIMITS[:, 0]) & (traj <= LIMITS[:, 1]))
    assert _means_free(model, scene, traj).all()
    assert (
        np.linalg.norm(np.diff(traj, axis=0), axis=-1).max() <= 0.0025 + TOL["float64_abs"]["atol"]
    )
    assert roadmap.validity.motions(traj[:-1], traj[1:]).all()
    # the straight line is blocked by the box, so the path bends
    assert len(path) > 2
    own = segment_owners(path, 0.0025)
    assert len(own) == len(traj) and own[0] == -1 and own[-1] == len(path) - 2


def test_interpolate_keeps_vertices():
    path = np.array([[0.0, 0.0], [0.01, 0.0], [0.01, 0.0035]])
    traj = interpolate_path(path, 0.0025)
    assert len(traj) == 1 + 4 + 2
    np.testing.assert_allclose(traj[4], path[1], **TOL["round_off"])


def test_same_seed_same_roadmap_and_trajectory(model, scene, roadmap):
    again = build_roadmap(MeanValidity(model, scene), n_milestones=60, seed=3)
    np.testing.assert_array_equal(again.vertices, roadmap.vertices)
    np.testing.assert_array_equal(again.edges, roadmap.edges)
    np.testing.assert_array_equal(
        again.shortest_path(START, GOAL), roadmap.shortest_path(START, GOAL)
    )
    other = build_roadmap(MeanValidity(model, scene), n_milestones=60, seed=4)
    assert not np.array_equal(other.vertices, roadmap.vertices)


def test_roadmap_reused_across_queries(roadmap):
    a = roadmap.shortest_path(START, GOAL)
    b = roadmap.shortest_path(GOAL, START)
    np.testing.assert_allclose(a, b[::-1], rtol=0, atol=0)
    n = roadmap.n_vertices
    roadmap.shortest_path(START, GOAL)
    assert roadmap.n_vertices == n  # queries do not add milestones


def test_no_path_names_roadmap_size(model, wall):
    rm = build_roadmap(MeanValidity(model, wall), n_milestones=30, seed=0)
    with pytest.raises(
        PlanningError, match=r"30 milestones \(\d+ connected\), \d+ edges, built in"
    ):
        rm.shortest_path(np.array([0.0, 0.0]), np.array([0.035, 0.0]))


def test_invalid_start_and_goal_outside_limits(roadmap):
    with pytest.raises(InvalidInputError, match=r"start: .*invalid"):
        roadmap.shortest_path(np.array([0.015, 0.015]), GOAL)
    with pytest.raises(InvalidInputError, match=r"goal: .*outside the displacement limits"):
        roadmap.shortest_path(START, np.array([0.05, 0.0]))
    with pytest.raises(InvalidInputError, match="goal"):
        roadmap.shortest_path(START, np.array([np.nan, 0.0]))


def test_goal_from_tip(roadmap, model):
    target = model.tip(np.array([0.031, 0.029]))
    g = goal_from_tip(roadmap, model, target, tolerance=0.002, seed=0)
    assert np.linalg.norm(tip_positions(model, g[None])[0] - target) <= 0.002
    assert roadmap.validity(g[None])[0]
    with pytest.raises(PlanningError, match="unreachable"):
        goal_from_tip(roadmap, model, [0.0, 0.0, 0.5], tolerance=0.002)
    with pytest.raises(
        PlanningError, match="unreachable"
    ):  # inside the box: no valid configuration there
        goal_from_tip(roadmap, model, [0.0, 0.0, 0.1], tolerance=0.002)


def test_options_checked(model, scene):
    v = MeanValidity(model, scene)
    with pytest.raises(InvalidInputError, match="resolution"):
        build_roadmap(v, n_milestones=10, resolution=float("nan"))
    with pytest.raises(InvalidInputError, match="n_milestones"):
        build_roadmap(v, n_milestones=1)


@pytest.mark.parametrize("step", [0, -1, float("nan"), float("inf"), 1e-320, True, "0.01"])
def test_interpolate_path_bad_step(step):
    with pytest.raises(InvalidInputError, match="step"):
        interpolate_path(np.array([[0.0, 0.0], [0.01, 0.02]]), step)


@pytest.mark.parametrize(
    "path", [np.array([0.0, 0.01]), np.zeros((0, 2)), np.array([[0.0, np.nan], [0.0, 0.0]])]
)
def test_interpolate_path_bad_path(path):
    with pytest.raises(InvalidInputError, match="path"):
        interpolate_path(path, 0.001)


def test_interpolate_path_over_budget_refused():
    from riskplan.errors import BudgetError

    with pytest.raises(BudgetError, match="step"):
        interpolate_path(np.array([[0.0, 0.0], [0.01, 0.02]]), 1e-12)
