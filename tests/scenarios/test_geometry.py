"""Planar geometry kernels of the scenarios against independent oracles (matplotlib's
point-in-path, the FEM package's point location, brute force)."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.scenarios import _geometry as geo


def test_points_in_polygon_matches_matplotlib(rng):
    from matplotlib.path import Path

    poly = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.5, 0.4], [0.0, 1.0]])  # non-convex
    pts = rng.uniform(-0.2, 1.2, (2000, 2))
    ours = geo.points_in_polygon(pts, poly)
    ref = Path(poly).contains_points(pts)
    assert np.array_equal(ours, ref)


def test_polygons_intersect_cases():
    sq = geo.rectangle_polygon((0, 0), (1, 1))
    assert geo.polygons_intersect(sq, geo.rectangle_polygon((0.9, 0.9), (2, 2)))  # overlap
    assert geo.polygons_intersect(sq, geo.rectangle_polygon((0.2, 0.2), (0.3, 0.3)))  # contained
    assert geo.polygons_intersect(geo.rectangle_polygon((0.2, 0.2), (0.3, 0.3)), sq)  # contains
    assert geo.polygons_intersect(
        sq, geo.rectangle_polygon((1.0, 0.2), (2.0, 0.3))
    )  # touching edge
    assert not geo.polygons_intersect(sq, geo.rectangle_polygon((1.01, 0.2), (2.0, 0.3)))
    assert not geo.polygons_intersect(
        sq, geo.rectangle_polygon((1.5, 0.0), (2.0, 1.0))
    )  # collinear, disjoint


def test_signed_distance(tol):
    sq = geo.rectangle_polygon((0, 0), (1, 1))
    d = geo.signed_distance_to_polygon(
        np.array([[0.5, 0.5], [1.5, 0.5], [2.0, 2.0], [1.0, 0.3]]), sq
    )
    np.testing.assert_allclose(d, [-0.5, 0.5, np.sqrt(2), 0.0], **tol["float64_ref"])


@pytest.mark.parametrize("n_elements", [60, 400])
def test_point_locator_matches_fem_locate(n_elements, rng, tol):
    from riskplan.deformable import locate, mesh_polygon

    outline = np.array([[0.0, 0.0], [0.7, 0.0], [1.0, 0.3], [1.0, 1.0], [0.0, 1.0]])
    mesh = mesh_polygon(outline, n_elements)
    loc = geo.PointLocator(mesh.nodes, mesh.triangles)
    pts = rng.uniform(0.0, 1.0, (300, 2))
    inside = geo.points_in_polygon(pts, outline)
    ref = locate(mesh, pts[inside])
    k = 0
    for p, ins in zip(pts, inside):
        e, lam = loc.locate(p)
        if not ins:
            assert e == -1
            continue
        # same point: equal barycentric interpolation of the node coordinates
        np.testing.assert_allclose(lam @ mesh.nodes[mesh.triangles[e]], p, **tol["float64_ref"])
        assert lam.min() >= -tol["barycentric"]["atol"]
        np.testing.assert_allclose(
            ref.positions(np.zeros((mesh.n_nodes, 2)))[k], p, **tol["float64_ref"]
        )
        k += 1
    assert loc.locate(np.array([5.0, 5.0]))[0] == -1
    assert loc.locate(np.array([-1e-3, 0.5]))[0] == -1


def test_numba_and_numpy_kernels_agree(rng, tol):
    if geo._locate_numba is None:
        pytest.skip("numba not installed")
    from riskplan.deformable import mesh_polygon, rectangle

    mesh = mesh_polygon(rectangle(), 200)
    loc = geo.PointLocator(mesh.nodes, mesh.triangles)
    for p in rng.uniform(0, 1, (50, 2)):
        cand = np.arange(mesh.n_elements)
        e1, _w1, l1 = geo._locate_numba(loc.maps, cand, p[0], p[1])
        e2, _w2, l2 = geo._locate_numpy(loc.maps, cand, p[0], p[1])
        assert e1 == e2
        np.testing.assert_allclose(l1, l2, **tol["float64_exact"])
