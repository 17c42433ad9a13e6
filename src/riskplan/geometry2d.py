"""Planar geometry shared by collision, the tissue FEM and the tissue scenarios.

Polygons are ``(k, 2)`` float64 vertex arrays, closed implicitly (the last vertex joins
the first). Sets of edges (the 2-D obstacles of :class:`riskplan.collision.Environment`:
closed, oriented loops) are ``segments (E, 4)`` with rows ``(x0, y0, x1, y1)``
(:func:`edge_segments`, :func:`polygon_segments`); the kernels read them contiguously,
which makes 2-D containment about 25 % cheaper than gathering through an index array.
Triangle meshes are ``nodes (N, 2)`` with ``triangles (T, 3)``.

Boundary convention (the one rule of this module): **sets are closed; contact counts.**

* A point on an edge or at a vertex of a polygon is *inside* it
  (:func:`points_in_polygon`, :func:`contains_points`).
* Two segments *intersect* when they share any point: a proper crossing, an endpoint on
  the other segment, a shared endpoint, or a collinear overlap (:func:`segments_intersect`,
  :func:`segments_hit`). Collinear segments with a gap between them do not intersect.
* Two polygons *intersect* when they overlap or touch (:func:`polygons_intersect`); a
  polygon whose non-adjacent edges touch is not simple (:func:`check_simple_polygon`).
* Distances are 0 on the boundary (:func:`point_polygon_distance`).
* A point lies in a triangle when its smallest barycentric coordinate is at least
  ``-BARYCENTRIC_TOL`` (:class:`TriangleLocator`), so points on shared edges and on the
  mesh boundary are found.

The predicates decide with the exact sign of orientation determinants
``orient(a, b, p) = (b - a) x (p - a)`` evaluated in float64 on the given coordinates, with
no tolerance: a point that lies on an edge in exact arithmetic but whose coordinates were
rounded (a point ``a + t (b - a)`` of a slanted edge) may land on either side. The one
exception is named: :func:`winding_numbers` returns integer winding numbers by the
half-open crossing rule (an edge counts when ``y0 <= y < y1`` or ``y1 <= y < y0``), which
is exact for points off the boundary and assigns boundary points to one side; callers that
need the closed set ask :func:`contains_points`.

Kernels are numba-compiled (``cache=True``); the scalar helpers (``orient``,
``segments_touch``, ``closest_point_on_segment``) are ``inline="always"`` so other kernels
(collision's whitened-space loop) use the same code. Callers validate; these functions
trust shapes and finiteness unless a docstring says otherwise.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from riskplan._triangles import BARYCENTRIC_TOL, TriangleLocator, barycentric_maps
from riskplan.errors import InvalidInputError

__all__ = [
    "BARYCENTRIC_TOL",
    "TriangleLocator",
    "barycentric_maps",
    "check_simple_polygon",
    "circle_polygon",
    "closest_point_on_segment",
    "closest_points_on_segments",
    "contains_points",
    "edge_segments",
    "orient",
    "point_polygon_distance",
    "points_in_polygon",
    "polygon_area",
    "polygon_edges",
    "polygon_segments",
    "polygons_intersect",
    "rectangle_polygon",
    "segments_hit",
    "segments_intersect",
    "segments_touch",
    "signed_distance_to_polygon",
    "winding_numbers",
]


# ------------------------------------------------------------------ constructors


def circle_polygon(center, radius: float, n: int = 24) -> np.ndarray:
    """``(n, 2)`` counter-clockwise regular polygon inscribed in a circle.

    Parameters
    ----------
    center : array_like, shape (2,)
        Centre.
    radius : float
        Circumradius.
    n : int
        Vertices.

    Returns
    -------
    numpy.ndarray
        ``(n, 2)`` vertices.
    """
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    c = np.asarray(center, dtype=np.float64)
    return c + radius * np.stack([np.cos(a), np.sin(a)], axis=1)


def rectangle_polygon(lower, upper) -> np.ndarray:
    """``(4, 2)`` counter-clockwise axis-aligned rectangle ``[lower, upper]``.

    Parameters
    ----------
    lower, upper : array_like, shape (2,)
        Opposite corners, ``lower <= upper``.

    Returns
    -------
    numpy.ndarray
        ``(4, 2)`` vertices.
    """
    (x0, y0), (x1, y1) = lower, upper
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)


def polygon_area(poly) -> float:
    """Signed area (shoelace formula): positive when ``poly (k, 2)`` is counter-clockwise.

    Parameters
    ----------
    poly : array_like, shape (k, 2)
        Vertices.

    Returns
    -------
    float
        ``½ Σ_i (x_i y_{i+1} − x_{i+1} y_i)``.
    """
    p = np.asarray(poly, dtype=np.float64)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def polygon_edges(k: int, offset: int = 0) -> np.ndarray:
    """``(k, 2)`` int64 directed edges ``i -> i + 1 (mod k)`` of a ``k``-gon, plus ``offset``.

    Parameters
    ----------
    k : int
        Vertices.
    offset : int
        Added to every index (the polygon's first vertex in a shared array).

    Returns
    -------
    numpy.ndarray
        ``(k, 2)`` int64 edges.
    """
    i = np.arange(k, dtype=np.int64)
    return np.column_stack([i, (i + 1) % k]) + offset


# ------------------------------------------------------------- scalar primitives


@nb.njit(cache=True, inline="always")
def orient(ax, ay, bx, by, px, py):
    """``(b - a) x (p - a)``: > 0 when ``p`` is left of ``a -> b``, 0 on its line."""
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@nb.njit(cache=True, inline="always")
def segments_touch(ax, ay, bx, by, cx, cy, dx, dy):
    """True when the closed segments ``ab`` and ``cd`` share a point (module convention).

    ``a`` and ``b`` straddle or touch the line of ``cd`` and ``c``, ``d`` straddle or touch
    the line of ``ab``; when all four points are collinear the segments intersect iff their
    bounding boxes overlap. Zero-length segments are points.
    """
    d1 = orient(cx, cy, dx, dy, ax, ay)
    d2 = orient(cx, cy, dx, dy, bx, by)
    d3 = orient(ax, ay, bx, by, cx, cy)
    d4 = orient(ax, ay, bx, by, dx, dy)
    if not ((d1 > 0.0) != (d2 > 0.0) or d1 == 0.0 or d2 == 0.0):
        return False
    if not ((d3 > 0.0) != (d4 > 0.0) or d3 == 0.0 or d4 == 0.0):
        return False
    if d1 == 0.0 and d2 == 0.0:  # collinear: the projections must overlap
        return not (
            max(ax, bx) < min(cx, dx)
            or max(cx, dx) < min(ax, bx)
            or max(ay, by) < min(cy, dy)
            or max(cy, dy) < min(ay, by)
        )
    return True


@nb.njit(cache=True, inline="always")
def closest_point_on_segment(ax, ay, bx, by, px, py):
    """Closest point ``(x, y)`` of segment ``ab`` to ``p`` (``a`` when ``a == b``)."""
    ex, ey = bx - ax, by - ay
    ee = ex * ex + ey * ey
    t = 0.0
    if ee > 0.0:
        t = ((px - ax) * ex + (py - ay) * ey) / ee
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
    return ax + t * ex, ay + t * ey


#: Count added by an edge that holds the query point (far above any winding number).
_ON_EDGE = 1 << 32


@nb.njit(cache=True)
def _crossing_counts(segments, points):
    """Per point: ``m * _ON_EDGE + w``, ``m`` the number of segments holding the point and
    ``w`` the half-open winding number of the other segments.

    An edge holding the point contributes no half-open increment (its orientation term
    ``c`` is 0), so ``w`` is the winding number of all edges. Kept as one loop over the
    contiguous ``(x0, y0, x1, y1)`` rows: it is the hot path of 2-D containment.
    """
    n = points.shape[0]
    out = np.zeros(n, dtype=np.int64)
    for i in range(n):
        px, py = points[i, 0], points[i, 1]
        w = 0
        for f in range(segments.shape[0]):
            x0, y0, x1, y1 = segments[f, 0], segments[f, 1], segments[f, 2], segments[f, 3]
            if y0 <= py:
                if y1 > py:  # upward across the ray's line
                    c = (x1 - x0) * (py - y0) - (px - x0) * (y1 - y0)
                    if c > 0.0:
                        w += 1
                    elif c == 0.0:
                        w += _ON_EDGE
                elif y1 == py:  # ends on the ray's line, from below or level
                    if px == x1 or (y0 == py and min(x0, x1) <= px <= max(x0, x1)):
                        w += _ON_EDGE
            elif y1 <= py:  # downward across (or onto) the ray's line
                c = (x1 - x0) * (py - y0) - (px - x0) * (y1 - y0)
                if c < 0.0:
                    w -= 1
                elif c == 0.0:
                    w += _ON_EDGE
        out[i] = w
    return out


@nb.njit(cache=True)
def _ring_segments(poly):
    k = poly.shape[0]
    out = np.empty((k, 4))
    for i in range(k):
        j = i + 1 if i + 1 < k else 0
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = poly[i, 0], poly[i, 1], poly[j, 0], poly[j, 1]
    return out


def polygon_segments(poly) -> np.ndarray:
    """``(k, 4)`` rows ``(x0, y0, x1, y1)`` of the edges ``i -> i + 1`` of ``poly (k, 2)``.

    Parameters
    ----------
    poly : array_like, shape (k, 2)
        Vertices.

    Returns
    -------
    numpy.ndarray
        ``(k, 4)`` segments.
    """
    return _ring_segments(_f64(poly))


def edge_segments(vertices, edges) -> np.ndarray:
    """``(E, 4)`` rows ``(x0, y0, x1, y1)`` of the directed ``edges (E, 2)`` over
    ``vertices (V, 2)``: the layout the edge-soup kernels read.

    Parameters
    ----------
    vertices : array_like, shape (V, 2)
        Vertices.
    edges : array_like, shape (E, 2)
        Directed edges as vertex indices.

    Returns
    -------
    numpy.ndarray
        ``(E, 4)`` contiguous float64 segments.
    """
    v = np.asarray(vertices, dtype=np.float64)
    e = np.asarray(edges)
    return np.ascontiguousarray(np.concatenate([v[e[:, 0]], v[e[:, 1]]], axis=1))


def winding_numbers(segments, points) -> np.ndarray:
    """Integer winding numbers ``(P,)`` of ``points (P, 2)`` w.r.t. closed, oriented loops
    of ``segments (E, 4)`` (:func:`edge_segments`), by the half-open crossing rule (see
    the module docstring): counter-clockwise loops count +1, clockwise loops -1.

    Parameters
    ----------
    segments : numpy.ndarray
        ``(E, 4)`` segments of closed, oriented loops.
    points : array_like, shape (P, 2)
        Query points.

    Returns
    -------
    numpy.ndarray
        ``(P,)`` int64 winding numbers.
    """
    c = _crossing_counts(segments, _f64(points))
    return c - _ON_EDGE * ((c + _ON_EDGE // 2) // _ON_EDGE)


def contains_points(segments, points) -> np.ndarray:
    """``(P,)`` bool: ``points (P, 2)`` in the closed region bounded by the loops of
    ``segments (E, 4)``: winding number > 0, or on a segment. Clockwise loops (holes)
    subtract; their edges belong to the region.

    Parameters
    ----------
    segments : numpy.ndarray
        ``(E, 4)`` segments of closed, oriented loops.
    points : array_like, shape (P, 2)
        Query points.

    Returns
    -------
    numpy.ndarray
        ``(P,)`` bool.
    """
    return _crossing_counts(segments, _f64(points)) > 0


def points_in_polygon(points, poly) -> np.ndarray:
    """``(P,)`` bool: True where a point of ``points (P, 2)`` is inside ``poly (k, 2)`` or on
    its boundary (a simple polygon in either orientation).

    Parameters
    ----------
    points : array_like, shape (P, 2)
        Query points.
    poly : array_like, shape (k, 2)
        A simple polygon.

    Returns
    -------
    numpy.ndarray
        ``(P,)`` bool.
    """
    return _crossing_counts(_ring_segments(_f64(poly)), _f64(points)) != 0


@nb.njit(cache=True)
def _segments_pairwise(a0, a1, b0, b1):
    out = np.zeros((a0.shape[0], b0.shape[0]), dtype=np.bool_)
    for i in range(a0.shape[0]):
        for j in range(b0.shape[0]):
            out[i, j] = segments_touch(
                a0[i, 0], a0[i, 1], a1[i, 0], a1[i, 1], b0[j, 0], b0[j, 1], b1[j, 0], b1[j, 1]
            )
    return out


def segments_intersect(a0, a1, b0, b1) -> np.ndarray:
    """``(A, B)`` bool: segment ``a0[i] -> a1[i]`` (``(A, 2)`` each) meets segment
    ``b0[j] -> b1[j]`` (``(B, 2)`` each); touching and collinear overlaps count.

    Parameters
    ----------
    a0, a1 : array_like, shape (A, 2)
        Start and end points of the first segments.
    b0, b1 : array_like, shape (B, 2)
        Start and end points of the second segments.

    Returns
    -------
    numpy.ndarray
        ``(A, B)`` bool.
    """
    return _segments_pairwise(_f64(a0), _f64(a1), _f64(b0), _f64(b1))


@nb.njit(cache=True)
def segments_hit(segments, p0, p1):
    """``(n,)`` bool: segment ``p0[i] -> p1[i]`` meets one of ``segments (E, 4)``
    (touching counts)."""
    n = p0.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        ax, ay, bx, by = p0[i, 0], p0[i, 1], p1[i, 0], p1[i, 1]
        for f in range(segments.shape[0]):
            if segments_touch(
                ax, ay, bx, by, segments[f, 0], segments[f, 1], segments[f, 2], segments[f, 3]
            ):
                out[i] = True
                break
    return out


@nb.njit(cache=True)
def _polygons_meet(p, q):
    kp, kq = p.shape[0], q.shape[0]
    for i in range(kp):
        i2 = i + 1 if i + 1 < kp else 0
        for j in range(kq):
            j2 = j + 1 if j + 1 < kq else 0
            if segments_touch(
                p[i, 0], p[i, 1], p[i2, 0], p[i2, 1], q[j, 0], q[j, 1], q[j2, 0], q[j2, 1]
            ):
                return True
    # no edge contact: they intersect iff one lies inside the other
    if _crossing_counts(_ring_segments(q), p[:1])[0] != 0:
        return True
    return _crossing_counts(_ring_segments(p), q[:1])[0] != 0


def polygons_intersect(p, q) -> bool:
    """True if two simple polygons ``(k, 2)`` overlap or touch (an edge contact, or one
    inside the other).

    Parameters
    ----------
    p, q : array_like, shape (k, 2)
        Simple polygons.

    Returns
    -------
    bool
        Whether they overlap or touch.
    """
    return bool(_polygons_meet(_f64(p), _f64(q)))


@nb.njit(cache=True)
def _first_self_contact(poly):
    """``(i, j)`` of the first pair of non-adjacent edges that touch, or ``(-1, -1)``."""
    k = poly.shape[0]
    for i in range(k):
        i2 = i + 1 if i + 1 < k else 0
        for j in range(i + 2, k):
            if i == 0 and j == k - 1:
                continue  # adjacent through vertex 0
            j2 = j + 1 if j + 1 < k else 0
            if segments_touch(
                poly[i, 0],
                poly[i, 1],
                poly[i2, 0],
                poly[i2, 1],
                poly[j, 0],
                poly[j, 1],
                poly[j2, 0],
                poly[j2, 1],
            ):
                return i, j
    return -1, -1


def check_simple_polygon(poly, name: str) -> np.ndarray:
    """Validate a simple polygon ``(k, 2)`` and return it counter-clockwise (a copy when it
    was reversed).

    Raises :class:`InvalidInputError` for fewer than 3 vertices, repeated consecutive
    vertices (an edge shorter than ``1e-12`` of the extent), zero area (below ``1e-12``
    of the squared extent) and self-intersection: non-adjacent edges that touch
    (closed rule of this module). Finiteness is the caller's check.

    Parameters
    ----------
    poly : array_like, shape (k, 2)
        Vertices, finite.
    name : str
        The argument, for messages.

    Returns
    -------
    numpy.ndarray
        ``(k, 2)`` float64 vertices, counter-clockwise.
    """
    p = np.asarray(poly, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3:
        raise InvalidInputError(
            f"{name}: a polygon needs at least 3 vertices as a (k, 2) array, got shape {p.shape}"
        )
    scale = float(np.ptp(p, axis=0).max()) or 1.0
    seg = np.roll(p, -1, axis=0) - p
    if np.any(np.linalg.norm(seg, axis=1) <= 1e-12 * scale):
        raise InvalidInputError(f"{name}: repeated consecutive vertices (zero-length edge)")
    area = polygon_area(p)
    if abs(area) <= 1e-12 * scale * scale:
        raise InvalidInputError(f"{name}: polygon has zero area (degenerate)")
    i, j = _first_self_contact(np.ascontiguousarray(p))
    if i >= 0:
        raise InvalidInputError(
            f"{name}: polygon self-intersects (edges {i} and {j} intersect; not a simple polygon)"
        )
    return p if area > 0 else p[::-1].copy()


# ------------------------------------------------------------------- distances


@nb.njit(cache=True)
def closest_points_on_segments(segments, points):
    """Exact closest points of ``points (n, 2)`` on ``segments (E, 4)`` (brute force).

    Returns ``(dist (n,), closest (n, 2), segment (n,))``; the first segment wins a tie.
    """
    n = points.shape[0]
    dist = np.full(n, np.inf)
    closest = np.zeros((n, 2))
    face = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        px, py = points[i, 0], points[i, 1]
        best = np.inf
        for f in range(segments.shape[0]):
            qx, qy = closest_point_on_segment(
                segments[f, 0], segments[f, 1], segments[f, 2], segments[f, 3], px, py
            )
            s = (qx - px) ** 2 + (qy - py) ** 2
            if s < best:
                best = s
                closest[i, 0], closest[i, 1] = qx, qy
                face[i] = f
        dist[i] = math.sqrt(best)
    return dist, closest, face


def point_polygon_distance(points, poly) -> np.ndarray:
    """``(P,)`` Euclidean distance from each point ``(P, 2)`` to the boundary of
    ``poly (k, 2)`` (0 on it).

    Parameters
    ----------
    points : array_like, shape (P, 2)
        Query points.
    poly : array_like, shape (k, 2)
        A polygon.

    Returns
    -------
    numpy.ndarray
        ``(P,)`` distances.
    """
    return closest_points_on_segments(polygon_segments(poly), _f64(points))[0]


def signed_distance_to_polygon(points, poly) -> np.ndarray:
    """``(P,)`` signed distance to ``poly``'s boundary: negative inside, 0 on the boundary,
    positive outside.

    Parameters
    ----------
    points : array_like, shape (P, 2)
        Query points.
    poly : array_like, shape (k, 2)
        A simple polygon.

    Returns
    -------
    numpy.ndarray
        ``(P,)`` signed distances.
    """
    pts = _f64(points)
    d = point_polygon_distance(pts, poly)
    return np.where(points_in_polygon(pts, poly), -d, d)


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)
