"""Procedural chest cavity: closed meshes, determinism, robot home shape free, bent shapes touch."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.collision import Environment, probability_of_collision
from riskplan.errors import InvalidInputError
from riskplan.kinematics.robot_mixture import arc_backbone, backbone_mixture
from riskplan.planning.chest_scene import ChestParams, build_chest
from tests.conftest import TOL


@pytest.fixture(scope="module")
def chest():
    return build_chest(0)


def test_meshes_closed_and_sized(chest):
    assert 3000 <= chest.n_triangles <= 50000
    for name, m in chest.meshes.items():
        assert m.is_watertight and m.is_winding_consistent, name
        assert m.volume > 0, name
    assert set(chest.environment.names) >= {
        "body_wall",
        "lung_left",
        "lung_right",
        "heart",
        "diaphragm",
        "spine",
        "rib0",
    }


def test_seeded(chest):
    again = build_chest(0)
    np.testing.assert_array_equal(again.environment.vertices, chest.environment.vertices)
    other = build_chest(1)
    assert not np.allclose(other.environment.vertices, chest.environment.vertices)


def test_base_frame(chest):
    R = chest.base_rotation
    np.testing.assert_allclose(R.T @ R, np.eye(3), **TOL["float64_ref"])
    np.testing.assert_allclose(np.linalg.det(R), 1.0, **TOL["float64_ref"])
    p = np.array([0.01, -0.02, 0.05])
    np.testing.assert_allclose(chest.to_base(chest.to_world(p)), p, **TOL["float64_ref"])
    np.testing.assert_allclose(
        chest.base_environment.vertices,
        chest.to_base(chest.environment.vertices),
        **TOL["float64_ref"],
    )
    # insertion point lies on the outer body wall; the base is inside the cavity, free
    wall = chest.environment.subset(["body_wall"])
    assert wall.closest_points(chest.insertion_point)[0] < 2e-3
    assert not chest.environment.contains(chest.base_position)
    # cavity interior is free, the wall and organs are not
    assert chest.environment.contains(
        np.array([0.0, 0.0, 0.0]) + [0, 0, -0.19 - 0.01]
    )  # inside the wall shell


def test_home_shape_free_and_bent_shapes_touch(chest):
    env = chest.base_environment
    s = np.linspace(0, 0.2, 81)
    home = np.column_stack([0 * s, 0 * s, s])
    assert not env.contains(home).any()
    # a 1 cm-radius body around the straight backbone stays clear too
    ring = (
        np.stack([np.cos(np.linspace(0, 2 * np.pi, 16)), np.sin(np.linspace(0, 2 * np.pi, 16))], 1)
        * 0.01
    )
    body = (home[None, :, :] + np.concatenate([ring, np.zeros((16, 1))], 1)[:, None, :]).reshape(
        -1, 3
    )
    assert not env.contains(body).any()
    bent = arc_backbone(np.array([8.0, 8.0]), np.array([0.0, np.pi]))
    assert env.contains(bent).any(axis=-1).all()
    # collision probabilities: small at home, large when bent into organs
    gm = backbone_mixture(np.concatenate([home[None, ::2], bent]), 5)
    p = probability_of_collision(gm, env)
    assert p[0] < 0.05 and np.all(p[1:] > 0.2)


def test_save_load_same_containment(tmp_path, chest):
    path = chest.save(tmp_path / "chest.stl")
    env = Environment.load(path)
    assert env.n_faces == chest.n_triangles
    pts = np.random.default_rng(0).uniform(-0.2, 0.2, size=(3000, 3))
    np.testing.assert_array_equal(env.contains(pts), chest.environment.contains(pts))


def test_parameters_validated():
    with pytest.raises(InvalidInputError, match="cavity_semi_axes"):
        build_chest(0, cavity_semi_axes=(0.1, -0.1, 0.2))
    with pytest.raises(InvalidInputError, match="subdivisions"):
        build_chest(0, ChestParams(subdivisions=9))
    finer = build_chest(0, subdivisions=4)
    assert finer.n_triangles > build_chest(0).n_triangles
