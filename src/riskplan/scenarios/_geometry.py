"""Small planar geometry kernels for the tissue scenarios (vectorised numpy; callers validate).

Polygons are ``(k, 2)`` vertex arrays, closed implicitly (last vertex joins the first).
"""

from __future__ import annotations

import numpy as np


def circle_polygon(center, radius: float, n: int = 24) -> np.ndarray:
    """``(n, 2)`` counter-clockwise regular polygon inscribed in a circle."""
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    c = np.asarray(center, dtype=np.float64)
    return c + radius * np.stack([np.cos(a), np.sin(a)], axis=1)


def rectangle_polygon(lower, upper) -> np.ndarray:
    """``(4, 2)`` counter-clockwise axis-aligned rectangle."""
    (x0, y0), (x1, y1) = lower, upper
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)


def points_in_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule: ``(P,)`` bool, True where a point of ``points (P, 2)`` is inside ``poly``."""
    x, y = points[:, 0:1], points[:, 1:2]
    x0, y0 = poly[None, :, 0], poly[None, :, 1]
    nxt = np.roll(poly, -1, axis=0)
    x1, y1 = nxt[None, :, 0], nxt[None, :, 1]
    cond = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.sum(cond & (x < xc), axis=1) % 2) == 1


def segments_intersect(
    a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray
) -> np.ndarray:
    """Proper or touching intersection of every segment ``a (A, 2)`` with every ``b (B, 2)``:
    ``(A, B)`` bool (collinear overlaps count as intersecting)."""

    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (
            r[..., 0] - p[..., 0]
        )

    A0, A1 = a0[:, None, :], a1[:, None, :]
    B0, B1 = b0[None, :, :], b1[None, :, :]
    d1 = orient(B0, B1, A0)
    d2 = orient(B0, B1, A1)
    d3 = orient(A0, A1, B0)
    d4 = orient(A0, A1, B1)
    proper = (d1 * d2 <= 0) & (d3 * d4 <= 0)
    # exclude the collinear-but-disjoint case that the <= test lets through
    colinear = (d1 == 0) & (d2 == 0)
    if np.any(colinear):
        lo_a = np.minimum(A0, A1)
        hi_a = np.maximum(A0, A1)
        lo_b = np.minimum(B0, B1)
        hi_b = np.maximum(B0, B1)
        overlap = np.all((lo_a <= hi_b) & (lo_b <= hi_a), axis=-1)
        proper = np.where(colinear, overlap, proper)
    return proper


def polygons_intersect(p: np.ndarray, q: np.ndarray) -> bool:
    """True if two simple polygons overlap or touch (edge crossing or containment)."""
    if segments_intersect(p, np.roll(p, -1, axis=0), q, np.roll(q, -1, axis=0)).any():
        return True
    return bool(points_in_polygon(p[:1], q)[0] or points_in_polygon(q[:1], p)[0])


def point_polygon_distance(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """``(P,)`` Euclidean distance from each point to the polygon's boundary (0 on it)."""
    a = poly[None, :, :]
    b = np.roll(poly, -1, axis=0)[None, :, :]
    p = points[:, None, :]
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-300), 0.0, 1.0)
    d = p - (a + t[..., None] * ab)
    return np.sqrt(np.min(np.sum(d * d, -1), axis=1))


def signed_distance_to_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """``(P,)`` signed distance: negative inside ``poly``, positive outside."""
    d = point_polygon_distance(points, poly)
    return np.where(points_in_polygon(points, poly), -d, d)


def _locate_numpy(maps, cand, x, y):
    M = maps[cand]
    lam = M[:, :, 0] * x + M[:, :, 1] * y + M[:, :, 2]
    worst = lam.min(1)
    k = int(worst.argmax())
    return int(cand[k]), float(worst[k]), lam[k]


try:  # numba is an optional extra ("fast"); the numpy path gives the same answers
    import numba as _nb

    @_nb.njit(cache=True)
    def _locate_numba(maps, cand, x, y):  # pragma: no cover - compiled
        best_e = -1
        best_w = -np.inf
        l0 = l1 = l2 = 0.0
        for c in cand:
            a0 = maps[c, 0, 0] * x + maps[c, 0, 1] * y + maps[c, 0, 2]
            a1 = maps[c, 1, 0] * x + maps[c, 1, 1] * y + maps[c, 1, 2]
            a2 = maps[c, 2, 0] * x + maps[c, 2, 1] * y + maps[c, 2, 2]
            w = min(a0, min(a1, a2))
            if w > best_w:
                best_w, best_e, l0, l1, l2 = w, c, a0, a1, a2
        out = np.empty(3)
        out[0] = l0
        out[1] = l1
        out[2] = l2
        return best_e, best_w, out

except ImportError:  # pragma: no cover - depends on the environment
    _locate_numba = None


class PointLocator:
    """Point location in a triangle mesh through a uniform grid (a few µs per query).

    Each grid cell lists the elements whose bounding box meets it; a query evaluates the
    barycentric coordinates ``λ = M_e [x, y, 1]`` of those elements only and keeps the
    one whose smallest coordinate is largest (inside when ``>= -tol``).
    """

    def __init__(
        self, nodes: np.ndarray, triangles: np.ndarray, cells: int | None = None, tol: float = 1e-10
    ):
        nodes = np.asarray(nodes, dtype=np.float64)
        triangles = np.asarray(triangles, dtype=np.int64)
        if cells is None:
            cells = max(2, int(np.sqrt(len(triangles) / 2.0)))
        self.tol = float(tol)
        self.lower = nodes.min(0)
        upper = nodes.max(0)
        self.size = np.maximum((upper - self.lower) / cells, 1e-300)
        self.cells = cells
        p = nodes[triangles]
        A = np.ones((len(triangles), 3, 3))
        A[:, 0, :] = p[:, :, 0]
        A[:, 1, :] = p[:, :, 1]
        self.maps = np.ascontiguousarray(np.linalg.inv(A))
        lo = np.floor((p.min(1) - self.lower) / self.size - 1e-9).astype(int).clip(0, cells - 1)
        hi = np.floor((p.max(1) - self.lower) / self.size + 1e-9).astype(int).clip(0, cells - 1)
        lists: list[list[int]] = [[] for _ in range(cells * cells)]
        for e in range(len(triangles)):
            for i in range(lo[e, 0], hi[e, 0] + 1):
                for j in range(lo[e, 1], hi[e, 1] + 1):
                    lists[i * cells + j].append(e)
        self.cand = [np.asarray(c if c else [0], dtype=np.int64) for c in lists]
        self._kernel = _locate_numba if _locate_numba is not None else _locate_numpy

    def locate(self, point) -> tuple[int, np.ndarray | None]:
        """``(element, λ (3,))`` of ``point (2,)``, or ``(-1, None)`` outside the mesh."""
        x, y = float(point[0]), float(point[1])
        i = int(np.floor((x - self.lower[0]) / self.size[0]))
        j = int(np.floor((y - self.lower[1]) / self.size[1]))
        if i < 0 or j < 0 or i > self.cells or j > self.cells:
            return -1, None
        cand = self.cand[min(i, self.cells - 1) * self.cells + min(j, self.cells - 1)]
        e, worst, lam = self._kernel(self.maps, cand, x, y)
        if worst < -self.tol:
            return -1, None
        return int(e), lam
