"""riskplan.geometry2d against independent oracles: hand-built boundary cases (the closed
convention: points on edges and vertices, touching and collinear segments), exact rational
arithmetic (fractions) on integer grids where every degeneracy occurs, winding numbers by
summed angles, matplotlib's point-in-path, batch kernels against scalar loops, and the FEM
package's point location."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from riskplan import geometry2d as geo
from riskplan.errors import InvalidInputError

# ------------------------------------------------------------------ exact oracles


def _fr(p):
    return Fraction(float(p[0])), Fraction(float(p[1]))


def _exact_on_segment(p, a, b) -> bool:
    """``p`` on the closed segment ``ab``, in exact rational arithmetic (parametric form)."""
    (px, py), (ax, ay), (bx, by) = _fr(p), _fr(a), _fr(b)
    ex, ey = bx - ax, by - ay
    if ex == 0 and ey == 0:
        return (px, py) == (ax, ay)
    if ex * (py - ay) != ey * (px - ax):
        return False
    t = ((px - ax) * ex + (py - ay) * ey) / (ex * ex + ey * ey)
    return 0 <= t <= 1


def _exact_segments_meet(a, b, c, d) -> bool:
    """Closed segments ``ab`` and ``cd`` share a point: solve ``a + s (b - a) = c + t (d - c)``
    exactly; parallel (or degenerate) pairs meet iff an endpoint lies on the other segment."""
    (ax, ay), (bx, by), (cx, cy), (dx, dy) = _fr(a), _fr(b), _fr(c), _fr(d)
    ux, uy, vx, vy = bx - ax, by - ay, dx - cx, dy - cy
    den = ux * vy - uy * vx
    if den == 0:
        return (
            _exact_on_segment(a, c, d)
            or _exact_on_segment(b, c, d)
            or _exact_on_segment(c, a, b)
            or _exact_on_segment(d, a, b)
        )
    wx, wy = cx - ax, cy - ay
    s = (wx * vy - wy * vx) / den
    t = (wx * uy - wy * ux) / den
    return 0 <= s <= 1 and 0 <= t <= 1


def _angle_winding(p, poly) -> int:
    """Winding number of ``p`` (off the boundary) as the summed turning angle / 2 pi."""
    v = poly - p
    a = np.arctan2(v[:, 1], v[:, 0])
    d = np.diff(np.append(a, a[0]))
    d = (d + np.pi) % (2 * np.pi) - np.pi
    return int(np.rint(d.sum() / (2 * np.pi)))


def _on_boundary(p, poly) -> bool:
    k = len(poly)
    return any(_exact_on_segment(p, poly[i], poly[(i + 1) % k]) for i in range(k))


def _grid_polygon(rng, k: int, n: int = 6) -> np.ndarray:
    """Random star-shaped polygon with distinct integer vertices in ``[0, n]^2`` (angular
    order about a non-lattice centre, so angles never tie)."""
    while True:
        pts = np.unique(rng.integers(0, n + 1, size=(3 * k, 2)), axis=0).astype(float)
        if len(pts) >= k:
            break
    pts = pts[rng.choice(len(pts), k, replace=False)]
    c = pts.mean(0) + np.array([0.0123, 0.00457])
    return pts[np.argsort(np.arctan2(pts[:, 1] - c[1], pts[:, 0] - c[0]))]


# --------------------------------------------------------- hand-built boundary cases

SQ = geo.rectangle_polygon((0.0, 0.0), (1.0, 1.0))


def test_points_on_edges_and_vertices_are_inside():
    on = np.array([[0.0, 0.5], [1.0, 0.5], [0.5, 0.0], [0.5, 1.0], [0, 0], [1, 0], [1, 1], [0, 1]])
    assert geo.points_in_polygon(on, SQ).all()
    assert geo.points_in_polygon(on, SQ[::-1]).all()  # either orientation
    off = np.array([[-1e-12, 0.5], [1.0 + 1e-12, 0.5], [0.5, 1.0 + 1e-12], [2.0, 1.0], [-1, 0]])
    assert not geo.points_in_polygon(off, SQ).any()
    tri = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])  # slanted edge through lattice points
    assert geo.points_in_polygon(np.array([[1.0, 3.0], [2.0, 2.0], [3.0, 1.0]]), tri).all()
    assert not geo.points_in_polygon(np.array([[2.0, 2.0 + 1e-12]]), tri)[0]
    segs = geo.edge_segments(SQ, geo.polygon_edges(4))
    np.testing.assert_array_equal(segs, geo.polygon_segments(SQ))
    assert geo.contains_points(segs, on).all()
    # the integer winding number keeps the half-open rule: left and bottom edges count
    w = geo.winding_numbers(segs, np.array([[0.0, 0.5], [1.0, 0.5], [0.5, 0.0]]))
    assert w.tolist() == [1, 0, 1]


@pytest.mark.parametrize(
    "a0, a1, b0, b1, meet",
    [
        ((0, 0), (2, 2), (0, 2), (2, 0), True),  # proper crossing
        ((0, 0), (1, 0), (1, 0), (2, 1), True),  # shared endpoint
        ((0, 0), (2, 0), (1, 0), (1, 1), True),  # T: endpoint on the other's interior
        ((0, 0), (2, 0), (1, 0), (3, 0), True),  # collinear overlap
        ((0, 0), (1, 0), (1, 0), (2, 0), True),  # collinear, touching at an endpoint
        ((0, 0), (1, 0), (2, 0), (3, 0), False),  # collinear with a gap
        ((0, 0), (1, 0), (0, 1), (1, 1), False),  # parallel
        ((0, 0), (2, 0), (1, 1e-12), (1, 1), False),  # near miss
        ((0, 0), (2, 0), (1, 0), (1, 0), True),  # zero-length segment on the other
        ((0, 0), (2, 0), (1, 1), (1, 1), False),  # zero-length segment off it
        ((1, 1), (1, 1), (1, 1), (1, 1), True),  # two equal points
        ((0, 0), (0, 2), (0, 1), (0, 3), True),  # vertical collinear overlap
        ((0, 0), (0, 1), (0, 2), (0, 3), False),  # vertical collinear gap
    ],
)
def test_segment_contact_cases(a0, a1, b0, b1, meet):
    args = [np.array([x], dtype=float) for x in (a0, a1, b0, b1)]
    assert geo.segments_intersect(*args)[0, 0] == meet
    assert geo.segments_intersect(args[2], args[3], args[0], args[1])[0, 0] == meet  # symmetric
    assert geo.segments_intersect(args[1], args[0], args[3], args[2])[0, 0] == meet  # reversed
    assert _exact_segments_meet(a0, a1, b0, b1) == meet  # the oracle agrees on the cases
    segs = np.array([[*b0, *b1]], dtype=float)
    assert geo.segments_hit(segs, args[0], args[1])[0] == meet


def test_polygon_contact_cases():
    sq = SQ
    R = geo.rectangle_polygon
    assert geo.polygons_intersect(sq, R((0.9, 0.9), (2, 2)))  # overlap
    assert geo.polygons_intersect(sq, R((1.0, 1.0), (2, 2)))  # touch at one vertex
    assert geo.polygons_intersect(sq, R((1.0, -1.0), (2, 2)))  # share an edge segment
    assert geo.polygons_intersect(sq, np.array([[0.5, 1.0], [1.0, 2.0], [0.0, 2.0]]))  # vertex
    assert not geo.polygons_intersect(sq, R((1.0 + 1e-12, 0.0), (2, 1)))


def test_simple_polygon_check_uses_the_closed_rule():
    # a vertex on a non-adjacent edge and two non-adjacent edges overlapping are contacts
    vertex_on_edge = np.array([[0, 0], [4, 0], [4, 4], [2, 0.0], [0, 4]], dtype=float)
    with pytest.raises(InvalidInputError, match="self-intersects"):
        geo.check_simple_polygon(vertex_on_edge, "p")
    # collinear non-adjacent edges with a gap between them are fine (a comb's teeth)
    comb = np.array([[0, 0], [5, 0], [5, 2], [4, 2], [4, 1], [1, 1], [1, 2], [0, 2]], float)
    out = geo.check_simple_polygon(comb, "p")
    np.testing.assert_array_equal(out, comb)
    np.testing.assert_array_equal(geo.check_simple_polygon(comb[::-1], "p"), comb[::-1][::-1])
    for bad, msg in (
        ([[0, 0], [1, 0]], "at least 3"),
        ([[0, 0], [1, 0], [1, 0], [0, 1]], "repeated"),
        ([[0, 0], [1, 0], [2, 0]], "zero area"),
        ([[0, 0], [2, 2], [2, 0], [0, 1]], "self-intersects"),
    ):
        with pytest.raises(InvalidInputError, match=msg):
            geo.check_simple_polygon(np.asarray(bad, dtype=float), "p")


def test_distances_on_the_boundary_are_zero(tol):
    on = np.array([[0.0, 0.5], [1.0, 1.0], [0.25, 0.0]])
    np.testing.assert_array_equal(geo.point_polygon_distance(on, SQ), 0.0)
    np.testing.assert_array_equal(geo.signed_distance_to_polygon(on, SQ), 0.0)


# ------------------------------------------------- random cases vs exact oracles


def test_segments_on_a_grid_match_exact_arithmetic(rng):
    # integer endpoints in [0, 3]^2: many shared endpoints, T-junctions, collinear overlaps
    a0, a1, b0, b1 = (rng.integers(0, 4, size=(60, 2)).astype(float) for _ in range(4))
    got = geo.segments_intersect(a0, a1, b0, b1)
    ref = np.array(
        [[_exact_segments_meet(p, q, r, s) for r, s in zip(b0, b1)] for p, q in zip(a0, a1)]
    )
    assert ref.any() and not ref.all()
    assert np.array_equal(got, ref)
    # the soup query is the pairwise test reduced over the edges
    segs = np.concatenate([b0, b1], axis=1)
    assert np.array_equal(geo.segments_hit(segs, a0, a1), ref.any(axis=1))


def test_random_polygons_match_brute_force(rng):
    outcomes = []
    for _ in range(40):
        poly = _grid_polygon(rng, int(rng.integers(3, 9)))
        k = len(poly)
        if abs(geo.polygon_area(poly)) == 0.0:
            continue
        pts = np.stack(np.meshgrid(np.arange(-1, 8), np.arange(-1, 8)), -1).reshape(-1, 2)
        pts = np.vstack([pts.astype(float), rng.uniform(-1, 7, (100, 2))])
        on = np.array([_on_boundary(p, poly) for p in pts])
        ref = on | np.array(
            [_angle_winding(p, poly) != 0 if not o else True for p, o in zip(pts, on)]
        )
        assert np.array_equal(geo.points_in_polygon(pts, poly), ref)
        segs = geo.polygon_segments(poly)
        assert np.array_equal(geo.contains_points(segs, pts), ref)
        off = ~on
        w = geo.winding_numbers(segs, pts[off])
        sign = 1 if geo.polygon_area(poly) > 0 else -1
        assert np.array_equal(w, sign * np.array([_angle_winding(p, poly) for p in pts[off]]))
        # simple-polygon check: rejected iff two non-adjacent edges meet (exact)
        contact = any(
            _exact_segments_meet(poly[i], poly[(i + 1) % k], poly[j], poly[(j + 1) % k])
            for i in range(k)
            for j in range(i + 2, k)
            if not (i == 0 and j == k - 1)
        )
        shuffled = poly[rng.permutation(k)]  # usually not simple
        contact_s = any(
            _exact_segments_meet(
                shuffled[i], shuffled[(i + 1) % k], shuffled[j], shuffled[(j + 1) % k]
            )
            for i in range(k)
            for j in range(i + 2, k)
            if not (i == 0 and j == k - 1)
        )
        for p, c in ((poly, contact), (shuffled, contact_s)):
            if abs(geo.polygon_area(p)) == 0.0 or np.any(np.all(p == np.roll(p, -1, 0), 1)):
                continue
            try:
                geo.check_simple_polygon(p, "p")
                rejected = False
            except InvalidInputError as e:
                assert "self-intersects" in str(e)
                rejected = True
            assert rejected == c
            outcomes.append(rejected)
    assert len(outcomes) > 40 and 0 < sum(outcomes) < len(outcomes)


def test_polygons_intersect_matches_brute_force(rng):
    for _ in range(40):
        p = _grid_polygon(rng, int(rng.integers(3, 7)), n=5)
        q = _grid_polygon(rng, int(rng.integers(3, 7)), n=5) + rng.integers(-3, 4, 2)
        if 0.0 in (geo.polygon_area(p), geo.polygon_area(q)):
            continue
        edges = any(
            _exact_segments_meet(p[i], p[(i + 1) % len(p)], q[j], q[(j + 1) % len(q)])
            for i in range(len(p))
            for j in range(len(q))
        )
        inside = _angle_winding(p[0], q) != 0 or _angle_winding(q[0], p) != 0
        assert geo.polygons_intersect(p, q) == (edges or inside)


def test_points_in_polygon_matches_matplotlib(rng):
    from matplotlib.path import Path

    poly = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.5, 0.4], [0.0, 1.0]])  # non-convex
    pts = rng.uniform(-0.2, 1.2, (2000, 2))
    ours = geo.points_in_polygon(pts, poly)
    ref = Path(poly).contains_points(pts)
    assert np.array_equal(ours, ref)


def test_closest_points_match_a_vectorised_formula(rng, tol):
    poly = geo.circle_polygon((0.3, -0.2), 0.7, 13)
    pts = rng.uniform(-1.5, 1.5, (500, 2))
    a, b = poly[None], np.roll(poly, -1, axis=0)[None]
    ab = b - a
    t = np.clip(np.sum((pts[:, None] - a) * ab, -1) / np.sum(ab * ab, -1), 0.0, 1.0)
    d = np.linalg.norm(pts[:, None] - (a + t[..., None] * ab), axis=-1)
    np.testing.assert_allclose(
        geo.point_polygon_distance(pts, poly), d.min(1), **tol["float64_exact"]
    )
    dist, closest, edge = geo.closest_points_on_segments(geo.polygon_segments(poly), pts)
    np.testing.assert_allclose(dist, d.min(1), **tol["float64_exact"])
    np.testing.assert_allclose(np.linalg.norm(closest - pts, axis=1), dist, **tol["float64_exact"])
    np.testing.assert_array_equal(edge, d.argmin(1))
    inside = geo.points_in_polygon(pts, poly)
    np.testing.assert_array_equal(
        geo.signed_distance_to_polygon(pts, poly), np.where(inside, -dist, dist)
    )


def test_overlapping_loops_add_up(rng):
    # two overlapping squares and a clockwise hole inside the first
    a = geo.rectangle_polygon((0, 0), (2, 2))
    b = geo.rectangle_polygon((1, 1), (3, 3))
    hole = geo.rectangle_polygon((0.2, 0.2), (0.6, 0.6))[::-1]
    V = np.vstack([a, b, hole])
    E = np.vstack([geo.polygon_edges(4), geo.polygon_edges(4, 4), geo.polygon_edges(4, 8)])
    segs = geo.edge_segments(V, E)
    pts = rng.uniform(-0.5, 3.5, (400, 2))
    ref = np.array(
        [_angle_winding(p, a) + _angle_winding(p, b) + _angle_winding(p, hole) for p in pts]
    )
    np.testing.assert_array_equal(geo.winding_numbers(segs, pts), ref)
    np.testing.assert_array_equal(geo.contains_points(segs, pts), ref > 0)
    # the hole's edge belongs to the (closed) solid; the edges inside the other square
    # are on the boundary of one and inside the other
    on = np.array([[0.2, 0.4], [0.4, 0.6], [0.6, 0.6], [1.5, 2.0], [2.0, 1.5], [2.0, 2.0]])
    assert geo.contains_points(segs, on).all()
    assert geo.winding_numbers(segs, np.array([[1.5, 1.5]]))[0] == 2


def test_polygons_intersect_cases():  # the scenarios' original cases
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
    loc = geo.TriangleLocator(mesh.nodes, mesh.triangles)
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


def test_locator_batch_scalar_and_exhaustive_agree(rng, tol):
    from riskplan.deformable import mesh_polygon, rectangle

    mesh = mesh_polygon(rectangle(), 200)
    loc = geo.TriangleLocator(mesh.nodes, mesh.triangles)
    np.testing.assert_array_equal(loc.maps, geo.barycentric_maps(mesh.nodes, mesh.triangles))
    # random points, the nodes (vertices of several elements), points on the boundary
    # edges (closed: inside) and just beyond them
    y = rng.uniform(0, 1, 30)
    pts = np.vstack(
        [
            rng.uniform(-0.1, 1.1, (300, 2)),
            mesh.nodes,
            np.column_stack([np.zeros(30), y]),
            np.column_stack([y, np.ones(30)]),
            np.column_stack([np.full(30, -1e-6), y]),
        ]
    )
    e_b, l_b = loc.locate_points(pts)
    lam_all = np.einsum("tij,pj->pti", loc.maps[:, :, :2], pts) + loc.maps[None, :, :, 2]
    best = lam_all.min(2).max(1)  # exhaustive oracle: the best element's smallest weight
    inside = best >= -geo.BARYCENTRIC_TOL
    np.testing.assert_array_equal(e_b >= 0, inside)
    assert inside[300 : 300 + mesh.n_nodes + 60].all() and not inside[-30:].any()
    # the chosen element holds the point: its weights reproduce the point
    xy = np.einsum("pa,pad->pd", l_b[inside], mesh.nodes[mesh.triangles[e_b[inside]]])
    np.testing.assert_allclose(xy, pts[inside], **tol["float64_ref"])
    assert (l_b[inside].min(1) >= -geo.BARYCENTRIC_TOL).all()
    for p, e, lam in zip(pts, e_b, l_b):
        e1, lam1 = loc.locate(p)
        assert e1 == e
        if e >= 0:
            np.testing.assert_array_equal(lam1, lam)
        else:
            assert lam1 is None
    assert loc.locate_points(np.array([[np.inf, 0.5], [1e300, -1e300]]))[0].tolist() == [-1, -1]
