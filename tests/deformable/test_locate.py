from __future__ import annotations

import numpy as np
import pytest

from riskplan.deformable import contains, locate
from riskplan.errors import InvalidInputError
from tests.conftest import TOL


def _random_inside(mesh, rng, n):
    e = rng.integers(0, mesh.n_elements, n)
    lam = rng.dirichlet(np.ones(3), n)
    return np.einsum("pa,pad->pd", lam, mesh.nodes[mesh.triangles[e]])


def test_interpolation_exact_for_linear_fields(poly200, rng, tol):
    pts = _random_inside(poly200, rng, 300)
    A, c = rng.normal(size=(2, 2)), rng.normal(size=2)
    u = poly200.nodes @ A.T + c
    it = locate(poly200, pts)
    np.testing.assert_allclose(it.interpolate(u), pts @ A.T + c, **tol["float64_exact"])
    np.testing.assert_allclose(it.positions(u), pts + pts @ A.T + c, **tol["float64_exact"])
    np.testing.assert_allclose(it.weights.sum(1), 1.0, **tol["float64_exact"])


def test_nodes_and_batches(poly200, rng, tol):
    it = locate(poly200, poly200.nodes)
    u = rng.normal(size=(4, poly200.n_nodes, 2))
    # at nodes, interpolation returns the nodal values; batch == loop
    np.testing.assert_allclose(it.interpolate(u), u, **tol["float64_exact"])


def test_spread_is_transpose_of_interpolate(poly200, rng, tol):
    it = locate(poly200, _random_inside(poly200, rng, 7))
    F = rng.normal(size=(7, 2))
    u = rng.normal(size=(poly200.n_nodes, 2))
    # virtual work: Σ F·u(X_p) = Σ f_a·u_a
    np.testing.assert_allclose(
        np.sum(F * it.interpolate(u)), np.sum(it.spread(F) * u), **tol["float64_exact"]
    )
    M = it.matrix().toarray()
    np.testing.assert_allclose(M @ u, it.interpolate(u), **tol["float64_exact"])
    np.testing.assert_allclose(it.spread(F).sum(0), F.sum(0), **tol["float64_exact"])


def test_boundary_points_are_inside(square175, tol):
    pts = np.array([[0.0, 0.3], [1.0, 1.0], [0.5, 1.0], [0.0, 0.0]])
    it = locate(square175, pts)
    u = square175.nodes * 2.0
    np.testing.assert_allclose(it.interpolate(u), 2.0 * pts, **tol["float64_exact"])


def test_outside_points_raise(square175):
    with pytest.raises(InvalidInputError, match="outside"):
        locate(square175, [[0.5, 0.5], [1.1, 0.5]])
    with pytest.raises(InvalidInputError, match="NaN"):
        locate(square175, [[np.nan, 0.5]])
    with pytest.raises(InvalidInputError, match="points"):
        locate(square175, np.zeros((2, 3)))
    assert contains(square175, [[0.5, 0.5], [1.1, 0.5], [-1e-6, 0.5]]).tolist() == [
        True,
        False,
        False,
    ]


def test_nonconvex_notch_is_outside(poly200):
    # (0.25, 0.8) is in the polygon's bounding box but above the notch edge (0.5,0.5)-(0,0.7)
    assert not contains(poly200, [[0.25, 0.8]])[0]
    assert contains(poly200, [[0.25, 0.3]])[0]


def test_tree_candidates_equal_exhaustive_search(rng, tol):
    """Candidate elements from a k-d tree never change the answer (fallback is exhaustive)."""
    from riskplan.deformable import mesh_polygon, rectangle
    from riskplan.deformable.material_points import locate_points

    mesh = mesh_polygon(rectangle(), 1000)
    pts = np.vstack([rng.uniform(-0.05, 1.05, size=(400, 2)), mesh.nodes[:50]])
    maps = mesh.barycentric_maps
    e_brute, l_brute = locate_points(maps, pts)
    bad_cand = rng.integers(0, mesh.n_elements, size=(len(pts), 3))  # mostly wrong candidates
    e_c, l_c = locate_points(maps, pts, candidates=bad_cand)
    inside = e_brute >= 0
    assert np.array_equal(e_c >= 0, inside)
    u = rng.normal(size=(mesh.n_nodes, 2))
    # the same interpolated values (a point on a shared edge may pick either element)
    v_brute = np.einsum("pad,pa->pd", u[mesh.triangles[e_brute[inside]]], l_brute[inside])
    v_c = np.einsum("pad,pa->pd", u[mesh.triangles[e_c[inside]]], l_c[inside])
    np.testing.assert_allclose(v_c, v_brute, **TOL["interpolation"])
    assert np.array_equal(contains(mesh, pts), inside)
    it = locate(mesh, pts[inside])
    np.testing.assert_allclose(it.interpolate(u), v_brute, **TOL["interpolation"])
