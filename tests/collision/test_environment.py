"""Environment: loaders, validation, containment, closest points, segment tests."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from matplotlib.path import Path as MplPath

import riskplan.collision._kernels as K
from riskplan.collision import Environment
from riskplan.errors import InvalidInputError
from tests.collision.conftest import box_mesh
from tests.conftest import TOL


def test_contains_matches_analytic_sphere_and_hollow_shell(rng):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    outer = trimesh.creation.icosphere(subdivisions=3, radius=2.0)
    inner = trimesh.creation.icosphere(subdivisions=3, radius=1.5)
    inner.invert()
    shell = trimesh.util.concatenate([outer, inner])
    env = Environment.from_meshes([sphere, shell], names=["ball", "shell"])
    pts = rng.uniform(-2.5, 2.5, size=(20000, 3))
    r = np.linalg.norm(pts, axis=1)
    # stay away from the faceted surfaces (icosphere chords lie within 1.3 % of the radius)
    clear = (np.abs(r - 1.0) > 0.03) & (np.abs(r - 1.5) > 0.03) & (np.abs(r - 2.0) > 0.04)
    expect = (r < 1.0) | ((r > 1.5) & (r < 2.0))
    got = env.contains(pts)
    np.testing.assert_array_equal(got[clear], expect[clear])
    w = env.winding_number(pts)
    assert set(np.unique(w[clear])) <= {0, 1}


def test_contains_agrees_with_trimesh_on_overlapping_boxes(rng, boxes_env):
    extra = box_mesh([1.5, -0.5, -0.5], [2.5, 0.5, 0.5])  # overlaps box "a"
    env = Environment.from_meshes([*(boxes_env.obstacle(i) for i in range(3)), extra])
    pts = rng.uniform(-3.5, 3.5, size=(5000, 3))
    ref = np.zeros(len(pts), bool)
    for i in range(env.n_obstacles):
        V, F = env.obstacle(i)
        ref |= trimesh.Trimesh(V, F, process=False).contains(pts)
    np.testing.assert_array_equal(env.contains(pts), ref)
    assert env.winding_number(np.array([2.0, 0.0, 0.0])) == 2


def test_contains_2d_matches_matplotlib(rng):
    polys = [
        np.array([[0.0, 0], [2, 0], [2, 2], [1, 0.5], [0, 2]]),
        np.array([[3.0, 3], [4, 3], [3.5, 4]]),
    ]
    env = Environment.from_polygons(polys)
    pts = rng.uniform(-1, 5, size=(5000, 2))
    ref = MplPath(polys[0]).contains_points(pts) | MplPath(polys[1]).contains_points(pts)
    np.testing.assert_array_equal(env.contains(pts), ref)
    # clockwise input is re-oriented
    env_cw = Environment.from_polygons([p[::-1] for p in polys])
    np.testing.assert_array_equal(env_cw.contains(pts), ref)


def test_closest_points_match_brute_force(rng, boxes_env):
    pts = rng.uniform(-3, 3, size=(300, 3))
    d, c, _f = boxes_env.closest_points(pts)
    db, cb, _ = K.closest_points_brute(boxes_env.vertices, boxes_env.faces, pts)
    np.testing.assert_allclose(d, db, **TOL["float64_ref"])
    np.testing.assert_allclose(c, cb, **TOL["closest_point"])
    sd = boxes_env.signed_distance(pts)
    np.testing.assert_array_equal(sd < 0, boxes_env.contains(pts))


def test_closest_points_2d():
    env = Environment.from_polygons([[[0, 0], [1, 0], [1, 1], [0, 1]]])
    d, c, _ = env.closest_points(np.array([[2.0, 0.5], [0.5, 0.5], [-1.0, -1.0]]))
    np.testing.assert_allclose(d, [1.0, 0.5, np.sqrt(2)], **TOL["float64_ref"])
    np.testing.assert_allclose(c[0], [1.0, 0.5], **TOL["float64_ref"])


def test_segments_collide_thin_obstacle():
    slab = box_mesh([-0.01, -1, -1], [0.01, 1, 1])
    env = Environment.from_meshes([slab])
    a = np.array([[-1.0, 0, 0], [-1.0, 2, 0], [-1.0, 0.2, 0.3]])
    b = np.array([[1.0, 0, 0], [1.0, 2, 0], [-0.5, 0.2, 0.3]])
    np.testing.assert_array_equal(env.segments_collide(a, b), [True, False, False])
    env2 = Environment.from_polygons([[[-0.01, -1], [0.01, -1], [0.01, 1], [-0.01, 1]]])
    np.testing.assert_array_equal(env2.segments_collide(a[:, :2], b[:, :2]), [True, False, False])


def test_save_and_load_roundtrip(tmp_path, boxes_env):
    for suffix in ("stl", "obj", "ply"):
        path = boxes_env.save(tmp_path / f"env.{suffix}")
        env = Environment.load(path)
        assert env.n_faces == boxes_env.n_faces
        pts = np.random.default_rng(0).uniform(-3, 3, size=(500, 3))
        np.testing.assert_array_equal(env.contains(pts), boxes_env.contains(pts))
    split = Environment.load(tmp_path / "env.stl", split=True)
    assert split.n_obstacles == 3


def test_from_arrays_and_subset(boxes_env):
    env = Environment.from_arrays(
        boxes_env.vertices, boxes_env.faces, boxes_env.face_obstacle, boxes_env.names
    )
    assert env.n_obstacles == 3 and env.dim == 3
    sub = env.subset(["a"])
    assert sub.n_obstacles == 1 and sub.contains(np.array([1.5, 0, 0]))
    assert not sub.contains(np.array([-1.0, 1.0, 0.0]))


def test_whitened_environment_preserves_containment(rng, boxes_env):
    mu = rng.normal(size=3)
    U = np.triu(rng.normal(size=(3, 3)))
    U[np.diag_indices(3)] = np.abs(U[np.diag_indices(3)]) + 0.5
    w = boxes_env.whitened(mu, U)
    pts = rng.uniform(-3, 3, size=(2000, 3))
    np.testing.assert_array_equal(w.contains((pts - mu) @ U.T), boxes_env.contains(pts))


@pytest.mark.parametrize(
    "make, msg",
    [
        (lambda: Environment.from_meshes([]), "empty"),
        (lambda: Environment.from_polygons([]), "empty"),
        (lambda: Environment(np.zeros((3, 3)), np.zeros((0, 3), int)), "empty"),
        (lambda: Environment.from_meshes([(np.zeros((4, 2)), np.array([[0, 1, 2]]))]), "shape"),
        (lambda: Environment.from_polygons([[[0, 0], [2, 2], [2, 0], [0, 1]]]), "self-intersects"),
        (lambda: Environment.from_polygons([[[0, 0], [1, 0], [2, 0]]]), "zero area"),
        (lambda: Environment.from_polygons([[[0, 0], [1, np.nan], [2, 0]]]), "NaN"),
        (lambda: Environment.from_polygons([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]]), "shape"),
    ],
)
def test_bad_environments(make, msg):
    with pytest.raises(InvalidInputError, match=msg):
        make()


def test_bad_meshes():
    box = box_mesh([0, 0, 0], [1, 1, 1])
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    with pytest.raises(InvalidInputError, match="not closed"):
        Environment.from_meshes([(V, F[:-1])])
    with pytest.raises(InvalidInputError, match="non-manifold"):
        # a face used twice: its edges have three faces
        Environment.from_meshes([(V, np.vstack([F, F[:1]]))])
    with pytest.raises(InvalidInputError, match="degenerate"):
        V2 = np.vstack([V, V[:1] + [0.0, 0.0, 0.0]])
        Environment.from_meshes([(V2, np.vstack([F, [[0, 1, 0]]]))])
    Vd = V.copy()
    Vd[F[0, 2]] = Vd[F[0, 0]] + 0.5 * (Vd[F[0, 1]] - Vd[F[0, 0]])  # collapse one triangle to a line
    with pytest.raises(InvalidInputError, match="zero-area"):
        Environment.from_meshes([(Vd, F)])
    with pytest.raises(InvalidInputError, match="NaN"):
        Environment.from_meshes([(np.full_like(V, np.nan), F)])
    # inverted orientation is fixed, not rejected
    env = Environment.from_meshes([(V, F[:, ::-1])])
    assert env.contains(np.array([0.5, 0.5, 0.5]))
    with pytest.raises(InvalidInputError, match="inwards"):
        Environment.from_meshes([(V, F[:, ::-1])], fix_orientation=False)


def test_query_dimension_errors(boxes_env):
    with pytest.raises(InvalidInputError, match=r"\(\.\.\., 3\)"):
        boxes_env.contains(np.zeros((4, 2)))
    with pytest.raises(InvalidInputError, match="NaN"):
        boxes_env.closest_points(np.array([np.nan, 0, 0]))
    with pytest.raises(InvalidInputError, match="shapes differ"):
        boxes_env.segments_collide(np.zeros((2, 3)), np.zeros((3, 3)))


def test_check_environment_names_the_argument_and_the_dimension(boxes_env):
    from riskplan.collision.environment import check_environment

    square = Environment.from_polygons([[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]])
    assert check_environment(boxes_env) is boxes_env
    assert check_environment(square, dim=2) is square
    with pytest.raises(InvalidInputError, match=r"^scene: expected an Environment, got str"):
        check_environment("chest", "scene")
    with pytest.raises(
        InvalidInputError, match=r"^environment: expected a 3-D Environment, got str"
    ):
        check_environment("chest", dim=3)
    with pytest.raises(InvalidInputError, match=r"expected a 3-D Environment, got a 2-D one"):
        check_environment(square, dim=3)


def test_load_errors(tmp_path):
    with pytest.raises(InvalidInputError, match="no such file"):
        Environment.load(tmp_path / "missing.stl")
    # an open surface (a single triangle) is rejected on load
    tri = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    tri.export(tmp_path / "open.stl")
    with pytest.raises(InvalidInputError, match="not closed"):
        Environment.load(tmp_path / "open.stl")


def test_non_finite_vertex_is_named(tmp_path):
    """A mesh with a NaN vertex names it, instead of reading as "not closed (watertight)"."""
    from riskplan.collision import Environment

    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    Environment.from_meshes([(v, f)])  # the tetrahedron itself is fine
    v[2, 1] = np.nan
    with pytest.raises(InvalidInputError, match="vertex 2 is not finite"):
        Environment.from_meshes([(v, f)])
    obj = tmp_path / "tet.obj"
    obj.write_text(
        "".join(f"v {a} {b} {c}\n" for a, b, c in v)
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f)
    )
    with pytest.raises(InvalidInputError, match="vertex 2 is not finite"):
        Environment.load(obj)
