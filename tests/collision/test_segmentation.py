"""Surface meshes from label maps (riskplan.collision.segmentation) against analytic solids.

Oracle: a sphere and a box, voxelised at the centres of a volume with identity and with a
non-identity frame (anisotropic spacing, offset origin, rotated and reflected direction), come
back with the analytic volume (within 3 %), centroid (within one voxel spacing) and surface
(symmetric Hausdorff distance at most one voxel spacing), before and after decimation.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from riskplan.collision import Environment
from riskplan.collision.mesh_files import load_environment, mesh_base_pose
from riskplan.collision.segmentation import (
    LabelVolume,
    check_metre_scale,
    decimate,
    label_surface,
    read_label_volume,
    save_segmentation_environment,
    segmentation_mesh,
)
from riskplan.errors import InvalidInputError
from tests.conftest import TOL

sitk = pytest.importorskip("SimpleITK")
pytest.importorskip("skimage")
pytest.importorskip("pymeshlab")

N = 48  # voxels per axis: the rotated box (half-diagonal 14.6 voxels) fits in every frame
LABEL = 3
# decimation target: at 1500 triangles the tilted box's corners are cut by 1.23 voxels, at 2000
# by 1.01, at 3000 by 0.92 (quadric collapse rounds corners the voxel grid does not align with)
FACES = 3000


def _rotation(a, b, c):
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("xyz", [a, b, c]).as_matrix()


FRAMES = {
    "identity": (np.ones(3), np.zeros(3), np.eye(3)),
    # millimetre-like spacing in metres, offset origin, rotated axes
    "rotated": (
        np.array([0.8e-3, 1.0e-3, 1.2e-3]),
        np.array([0.05, -0.03, 0.02]),
        _rotation(0.3, -0.5, 0.9),
    ),
    # a left-handed index frame (det D = -1), as LPS volumes stored with a flipped axis have
    "reflected": (
        np.array([1.1e-3, 0.9e-3, 1.0e-3]),
        np.array([-0.01, 0.02, 0.0]),
        _rotation(-0.2, 0.4, 0.1) @ np.diag([1.0, 1.0, -1.0]),
    ),
}


def _volume(inside, spacing, origin, direction) -> LabelVolume:
    """Label ``LABEL`` at the voxel centres where ``inside(x)``; a second label beside it."""
    k, j, i = np.meshgrid(*[np.arange(N)] * 3, indexing="ij")
    ijk = np.stack([i, j, k], axis=-1).astype(float)
    X = origin + (ijk * spacing) @ direction.T
    labels = np.where(inside(X), LABEL, 0).astype(np.uint8)
    labels[0, 0, :3] = 7  # another label elsewhere: must not leak into LABEL's surface
    return LabelVolume(labels, spacing, origin, direction)


def _sphere(spacing, origin, direction):
    h = spacing.max()
    c = origin + direction @ (spacing * (N - 1) / 2)
    R = 12.0 * h  # radius >= 10 voxels along every axis
    return (
        lambda X: np.linalg.norm(X - c, axis=-1) <= R,
        4.0 / 3.0 * np.pi * R**3,
        c,
        lambda P: np.abs(np.linalg.norm(P - c, axis=-1) - R),
        lambda n, rng: c + R * _unit(rng.normal(size=(n, 3))),
    )


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _box(spacing, origin, direction):
    h = spacing.max()
    # box axes are not the voxel axes: a rotated box in a rotated volume
    B = _rotation(0.2, 0.1, -0.3)
    c = origin + direction @ (spacing * (N - 1) / 2)
    half = np.array([10.0, 7.0, 8.0]) * h

    def local(X):
        return (X - c) @ B

    def sdf_abs(P):
        q = np.abs(local(P)) - half
        outside = np.linalg.norm(np.maximum(q, 0), axis=-1)
        inside = np.minimum(q.max(axis=-1), 0)
        return np.abs(outside + inside)

    def surface(n, rng):
        # uniform on the faces, corners and edges included (area-weighted face choice)
        areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]]).repeat(2)
        f = rng.choice(6, size=n, p=areas / areas.sum())
        u = rng.uniform(-1, 1, size=(n, 3)) * half
        axis, sign = f // 2, np.where(f % 2 == 0, 1.0, -1.0)
        u[np.arange(n), axis] = sign * half[axis]
        corners = np.array(np.meshgrid(*[[-1, 1]] * 3, indexing="ij")).reshape(3, -1).T * half
        return c + np.concatenate([u, corners]) @ B.T

    return (
        lambda X: np.all(np.abs(local(X)) <= half, axis=-1),
        float(np.prod(2 * half)),
        c,
        sdf_abs,
        surface,
    )


def _check_shape(V, F, volume, centroid, dist, surface, h, rng):
    env = Environment(V, F)  # validates: closed, edge-manifold, consistently oriented
    m = trimesh.Trimesh(env.vertices, env.faces, process=False)
    assert m.volume > 0  # outward faces
    assert m.volume == pytest.approx(volume, rel=TOL["segmentation_volume"]["rtol"])
    assert np.linalg.norm(m.center_mass - centroid) <= h
    # Hausdorff: mesh -> shape at the vertices and on sampled surface points, shape -> mesh
    assert dist(V).max() <= h
    assert dist(m.sample(4000, seed=1)).max() <= h
    _, d, _ = trimesh.proximity.closest_point(m, surface(4000, rng))
    assert d.max() <= h


@pytest.mark.parametrize("frame", list(FRAMES))
@pytest.mark.parametrize("shape", [_sphere, _box])
def test_label_surface_matches_the_analytic_solid_before_and_after_decimation(shape, frame, rng):
    spacing, origin, direction = FRAMES[frame]
    inside, volume, centroid, dist, surface = shape(spacing, origin, direction)
    vol = _volume(inside, spacing, origin, direction)
    h = float(spacing.max())
    V, F = label_surface(vol, LABEL)
    _check_shape(V, F, volume, centroid, dist, surface, h, rng)
    V2, F2 = decimate(V, F, FACES)
    assert len(F2) <= FACES < len(F)
    _check_shape(V2, F2, volume, centroid, dist, surface, h, rng)


@pytest.mark.parametrize("suffix", [".nrrd", ".nii.gz"])
def test_files_carry_the_physical_frame(tmp_path, suffix, rng):
    """Written by SimpleITK with a non-identity frame and read back: the same surface as the
    in-memory volume (NIfTI's RAS axes are converted back to LPS on reading)."""
    spacing, origin, direction = FRAMES["rotated"]
    inside, volume, centroid, dist, surface = _sphere(spacing, origin, direction)
    vol = _volume(inside, spacing, origin, direction)
    img = sitk.GetImageFromArray(vol.labels)
    img.SetSpacing(spacing.tolist())
    img.SetOrigin(origin.tolist())
    img.SetDirection(direction.ravel().tolist())
    path = tmp_path / f"labels{suffix}"
    sitk.WriteImage(img, str(path))
    back = read_label_volume(path)
    np.testing.assert_array_equal(back.labels, vol.labels)
    np.testing.assert_allclose(back.direction, direction, **TOL["float32_rounding"])
    # before decimation the two surfaces agree vertex for vertex (the file's frame to round-off)
    V0, F0 = label_surface(vol, LABEL)
    V1, F1 = label_surface(back, LABEL)
    np.testing.assert_array_equal(F1, F0)
    np.testing.assert_allclose(V1, V0, **TOL["float32_rounding"])
    V, F, info = segmentation_mesh(path, LABEL, faces=FACES)
    assert info["triangles"] == len(F) <= FACES
    assert info["marching_cubes_triangles"] == len(F0)
    _check_shape(V, F, volume, centroid, dist, surface, float(spacing.max()), rng)


def test_absent_label_is_named_with_the_labels_present(tmp_path):
    vol = _volume(lambda X: np.linalg.norm(X - 20, axis=-1) < 12, *FRAMES["identity"])
    with pytest.raises(
        InvalidInputError, match=r"--label 5: no voxel has this label; labels present: 3, 7"
    ):
        label_surface(vol, 5)
    empty = LabelVolume(np.zeros((4, 4, 4), np.uint8), np.ones(3), np.zeros(3), np.eye(3))
    with pytest.raises(InvalidInputError, match="empty volume"):
        label_surface(empty, 1)


def test_millimetres_where_metres_are_expected_are_said():
    # a 150 mm organ given in millimetres, judged against a 0.12 m robot
    V = np.array([[0.0, 0, 0], [150.0, 80, 60]])
    with pytest.raises(
        InvalidInputError, match=r"times the robot's length \(0.12 m\).*millimetres.*--scale 0.001"
    ):
        check_metre_scale(V, 0.12, remedy="Scale them by 0.001 (--scale 0.001)")
    with pytest.raises(InvalidInputError, match=r"^organ.stl: .*millimetres.*by 0.001 before use"):
        check_metre_scale(V, 0.12, source="organ.stl")
    np.testing.assert_allclose(
        check_metre_scale(V * 1e-3, 0.12), np.linalg.norm([0.15, 0.08, 0.06]), **TOL["float64_ref"]
    )


def test_sidecar_names_the_frame_and_leaves_an_unknown_pose_to_the_planner(tmp_path):
    spacing, origin, direction = FRAMES["rotated"]
    inside, *_ = _sphere(spacing, origin, direction)
    vol = _volume(inside, spacing, origin, direction)
    V, F = label_surface(vol, LABEL)
    info = {"label": LABEL, "source": "test"}
    out = save_segmentation_environment(V, F, tmp_path / "organ.stl", info=info)
    with pytest.raises(InvalidInputError, match="base pose in the mesh's frame is unknown"):
        mesh_base_pose(out)
    out2 = save_segmentation_environment(
        V, F, tmp_path / "organ2.stl", info=info, base_pose="identity"
    )
    env = load_environment(out2)  # the STL stores float32 and reorders vertices
    assert env.n_faces == len(F)
    order = np.lexsort(np.round(env.vertices, 6).T), np.lexsort(np.round(V, 6).T)
    np.testing.assert_allclose(env.vertices[order[0]], V[order[1]], **TOL["float32_vertices"])
