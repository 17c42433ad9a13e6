from __future__ import annotations

import numpy as np
import pytest

from riskplan.deformable import TissueMesh, mesh_polygon, rectangle
from riskplan.deformable.elements import boundary_edges, signed_areas
from riskplan.errors import InvalidInputError


@pytest.mark.parametrize("n", [50, 51, 57, 100, 174, 175, 333, 500, 777, 999, 1000])
@pytest.mark.parametrize("shape", ["square", "poly"])
def test_element_count_is_hit(n, shape, tol, poly_vertices):
    verts = rectangle() if shape == "square" else poly_vertices
    m = mesh_polygon(verts, n)
    assert m.n_elements == n
    # the mesh covers the polygon exactly
    x, y = verts[:, 0], verts[:, 1]
    area = 0.5 * abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    np.testing.assert_allclose(m.area, area, **tol["float64_exact"])
    assert np.all(m.areas > 0)


def test_corners_and_keep_points_are_nodes(tol):
    keep = np.array([[0.5, 0.5], [0.5, 0.0], [0.3, 0.7], [1.0, 1.0]])
    m = mesh_polygon(rectangle(), 175, keep_points=keep)
    assert m.n_elements == 175
    np.testing.assert_allclose(m.nodes[m.vertex_nodes], rectangle(), **tol["float64_exact"])
    np.testing.assert_allclose(m.nodes[m.kept_nodes], keep, **tol["float64_exact"])


def test_clockwise_polygon_keeps_vertex_order(tol):
    cw = rectangle()[::-1]
    m = mesh_polygon(cw, 120)
    np.testing.assert_allclose(m.nodes[m.vertex_nodes], cw, **tol["float64_exact"])
    assert np.all(signed_areas(m.nodes, m.triangles) > 0)


def test_boundary_edges_form_closed_ccw_loop(square175, tol):
    be = square175.boundary_edges
    # every boundary node starts exactly one edge and ends exactly one edge
    assert np.array_equal(np.sort(be[:, 0]), np.sort(be[:, 1]))
    # the boundary encloses the mesh area (shoelace over edges)
    p, q = square175.nodes[be[:, 0]], square175.nodes[be[:, 1]]
    enclosed = 0.5 * np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1])
    np.testing.assert_allclose(enclosed, square175.area, **tol["float64_exact"])


def test_boundary_edges_of_two_triangles():
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    be = {tuple(e) for e in boundary_edges(tri)}
    assert be == {(0, 1), (1, 2), (2, 3), (3, 0)}


def test_mesh_is_deterministic(poly_vertices):
    a = mesh_polygon(poly_vertices, 300)
    b = mesh_polygon(poly_vertices, 300)
    assert np.array_equal(a.nodes, b.nodes) and np.array_equal(a.triangles, b.triangles)


def test_arrays_are_read_only(square175):
    with pytest.raises(ValueError):
        square175.nodes[0, 0] = 1.0


def test_inverted_triangle_is_rejected():
    nodes = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    with pytest.raises(InvalidInputError, match="inverted"):
        TissueMesh(nodes, np.array([[0, 1, 2], [0, 3, 2]]))


def test_degenerate_triangle_is_rejected():
    nodes = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [0.0, 1.0]])
    with pytest.raises(InvalidInputError, match="degenerate"):
        TissueMesh(nodes, np.array([[0, 1, 3], [0, 1, 2]]))


@pytest.mark.parametrize(
    "nodes, tris, match",
    [
        (np.zeros((3, 3)), [[0, 1, 2]], "nodes"),
        ([[0, 0], [1, 0], [0, 1]], [[0, 1, 5]], "triangles"),
        ([[0, 0], [1, 0], [0, 1], [5, 5]], [[0, 1, 2]], "no triangle"),
        ([[0, 0], [1, 0], [np.nan, 1]], [[0, 1, 2]], "NaN"),
        ([[0, 0], [1, 0], [0, 1]], [[0, 1, 2.5]], "integer"),
    ],
)
def test_bad_mesh_arrays(nodes, tris, match):
    with pytest.raises(InvalidInputError, match=match):
        TissueMesh(np.asarray(nodes, dtype=float), np.asarray(tris))


@pytest.mark.parametrize(
    "verts, n, keep, match",
    [
        (rectangle(), 1, None, "coarsest"),
        (rectangle(), 0, None, "n_elements"),
        (rectangle(), 100.0, None, "n_elements"),
        ([[0, 0], [1, 0]], 100, None, "at least 3"),
        ([[0, 0], [2, 2], [2, 0], [0, 1]], 100, None, "intersect"),
        ([[0, 0], [1, 0], [2, 0]], 100, None, "zero area"),
        (rectangle(), 100, [[2.0, 0.5]], "outside"),
        (rectangle(), 100, [[np.nan, 0.5]], "NaN"),
    ],
)
def test_bad_polygon_input(verts, n, keep, match):
    with pytest.raises(InvalidInputError, match=match):
        mesh_polygon(np.asarray(verts, dtype=float), n, keep_points=keep)


def test_derived_arrays_are_cached_read_only_properties(square175):
    from riskplan.deformable import elements

    mesh = mesh_polygon(rectangle(), 60)
    for name, fn in (
        ("shape_gradients", elements.shape_gradients),
        ("barycentric_maps", elements.barycentric_maps),
    ):
        first = getattr(mesh, name)
        assert getattr(mesh, name) is first  # computed once
        assert not first.flags.writeable
        np.testing.assert_array_equal(first, fn(mesh.nodes, mesh.triangles))
    assert mesh.locator is mesh.locator
    assert mesh.boundary_edges is mesh.boundary_edges and not mesh.boundary_edges.flags.writeable


def test_deformable_modules_import_without_cycles():
    """Each module of the package imports only modules listed before it (one direction)."""
    import ast
    from pathlib import Path

    import riskplan.deformable as pkg

    order = [
        "elements",
        "mesh",
        "material",
        "laws",
        "nhkernels",
        "banded",
        "assembly",
        "material_points",
        "loads",
        "linear",
        "newton",
        "hyperelastic",
        "tetmesh",
        "tetassembly",
        "tetlocate",
        "tetfactor",
        "tetnewton",
        "tissue3d",
    ]
    root = Path(pkg.__file__).parent
    assert sorted(order) == sorted(p.stem for p in root.glob("*.py") if p.stem != "__init__")
    for k, name in enumerate(order):
        tree = ast.parse((root / f"{name}.py").read_text())
        deps = {
            n.module.split(".")[2]
            for n in ast.walk(tree)
            if isinstance(n, ast.ImportFrom)
            and n.module
            and n.module.startswith("riskplan.deformable.")
        }
        deps |= {
            a.name
            for n in ast.walk(tree)
            if isinstance(n, ast.ImportFrom) and n.module == "riskplan.deformable"
            for a in n.names
        } & set(order)
        assert deps <= set(order[:k]), (name, deps - set(order[:k]))
