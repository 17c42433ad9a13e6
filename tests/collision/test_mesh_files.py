"""Environment frames: base poses, mesh files with sidecars, the same scene by every path."""

from __future__ import annotations

import json

import numpy as np
import pytest

from riskplan.collision import (
    BasePose,
    Environment,
    environment_in_base_frame,
    gaussian_bound,
    load_environment,
    save_environment,
)
from riskplan.errors import DataFormatError, InvalidInputError
from tests.collision.conftest import box_mesh
from tests.conftest import TOL


def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


@pytest.fixture
def world_scene(rng):
    base_env = Environment.from_meshes(
        [
            box_mesh([0.05, -0.02, 0.0], [0.08, 0.02, 0.1]),
            box_mesh([-0.2, -0.2, 0.2], [0.2, 0.2, 0.25]),
        ]
    )
    pose = BasePose(rng.normal(size=3), _rotation(rng))
    world = Environment(
        pose.to_world(base_env.vertices), base_env.faces, base_env.face_obstacle, base_env.names
    )
    return base_env, world, pose


def test_pose_round_trip_and_quaternion(rng, tol):
    pose = BasePose(rng.normal(size=3), _rotation(rng))
    x = rng.normal(size=(5, 3))
    np.testing.assert_allclose(pose.to_base(pose.to_world(x)), x, **tol["float64_ref"])
    # 90 degrees about z: base x axis = world y axis
    q = BasePose.from_quaternion([1.0, 2.0, 3.0], [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    np.testing.assert_allclose(q.rotation[:, 0], [0, 1, 0], **tol["float64_ref"])
    np.testing.assert_allclose(
        BasePose.parse("1,2,3,0.7071067811865476,0,0,0.7071067811865476").rotation,
        q.rotation,
        **tol["float64_ref"],
    )
    assert np.array_equal(BasePose.parse("identity").rotation, np.eye(3))


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: BasePose([0, 0], np.eye(3)), "position"),
        (lambda: BasePose([0, 0, np.nan], np.eye(3)), "position"),
        (lambda: BasePose([0, 0, 0], 2 * np.eye(3)), "rotation"),
        (lambda: BasePose([0, 0, 0], -np.eye(3)), "rotation"),  # a reflection
        (lambda: BasePose(["a", 0, 0], np.eye(3)), "position"),
        (lambda: BasePose.from_quaternion([0, 0, 0], [0, 0, 0, 0]), "non-zero"),
        (lambda: BasePose.parse("1,2,3"), "7"),
        (lambda: BasePose.parse("1,2,x,1,0,0,0"), "x,y,z"),
        (lambda: BasePose.parse(""), "identity"),
        (lambda: BasePose.parse(None), "identity"),
    ],
)
def test_bad_poses_are_named_errors(make, match):
    with pytest.raises(InvalidInputError, match=match):
        make()


def test_saved_world_mesh_loads_in_the_base_frame(tmp_path, world_scene, rng, tol):
    base_env, world, pose = world_scene
    path = save_environment(
        world, tmp_path / "scene.ply", base_pose=pose, metadata={"note": "test"}
    )
    meta = json.loads((tmp_path / "scene.ply.json").read_text())
    assert meta["frame"] == "world" and meta["note"] == "test"
    loaded = load_environment(path)
    mu = rng.normal(size=(6, 3)) * 0.05
    U = np.broadcast_to(np.eye(3) / 0.02, (6, 3, 3))
    # (mesh files store float32 vertices)
    np.testing.assert_allclose(
        gaussian_bound(mu, U, loaded), gaussian_bound(mu, U, base_env), **TOL["float32_mesh_bound"]
    )
    # an explicit pose (here the same one, from the sidecar file) gives the same environment
    explicit = load_environment(path, base_pose=BasePose.from_json(tmp_path / "scene.ply.json"))
    np.testing.assert_allclose(explicit.vertices, loaded.vertices, **tol["float64_exact"])


def test_base_frame_mesh_and_missing_frame(tmp_path, world_scene):
    base_env, world, _pose = world_scene
    path = save_environment(base_env, tmp_path / "base.stl")
    assert json.loads((tmp_path / "base.stl.json").read_text())["frame"] == "base"
    np.testing.assert_allclose(
        load_environment(path).bounds, base_env.bounds, **TOL["float32_vertices"]
    )
    (tmp_path / "base.stl.json").unlink()
    with pytest.raises(InvalidInputError, match="frame is unknown"):
        load_environment(path)
    assert load_environment(path, base_pose=BasePose.identity()).n_faces == base_env.n_faces
    (tmp_path / "base.stl.json").write_text('{"frame": "robot"}')
    with pytest.raises(DataFormatError, match="frame"):
        load_environment(path)
    (tmp_path / "base.stl.json").write_bytes(b"\xff\xfe not json")
    with pytest.raises(DataFormatError, match="JSON"):
        load_environment(path)
    with pytest.raises(InvalidInputError, match="mesh file"):
        save_environment(base_env, tmp_path / "c.xyz")
    with pytest.raises(InvalidInputError, match="BasePose"):
        environment_in_base_frame(world, (np.zeros(3), np.eye(3)))


def test_chest_file_round_trip(tmp_path):
    from riskplan.planning.chest_scene import build_chest

    chest = build_chest(0, subdivisions=1)
    path = chest.save(tmp_path / "chest.stl")
    loaded = load_environment(path)
    mu = np.array([[0.0, 0.0, 0.05], [0.01, 0.0, 0.12], [0.0, 0.02, 0.18]])
    U = np.broadcast_to(np.eye(3) / 0.01, (3, 3, 3))
    np.testing.assert_allclose(
        gaussian_bound(mu, U, loaded),
        gaussian_bound(mu, U, chest.base_environment),
        **TOL["float32_mesh_bound"],
    )
