"""Point location in triangle meshes: the barycentric maps of the elements and a uniform-grid
locator (:class:`riskplan.geometry2d.TriangleLocator`). Part of :mod:`riskplan.geometry2d`,
which exports these names and states the boundary convention; kept in a module of its own so
that each stays within the size measure."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

#: A point is in a triangle when its smallest barycentric coordinate is >= -BARYCENTRIC_TOL.
BARYCENTRIC_TOL = 1e-10


def barycentric_maps(nodes, triangles) -> np.ndarray:
    """``(T, 3, 3)`` matrices ``M_e`` with ``λ = M_e @ [x, y, 1]`` (inverse of the affine
    map ``[x; y; 1] = [[x_a], [y_a], [1]] λ``) of triangles ``(T, 3)`` over ``nodes (N, 2)``.

    Parameters
    ----------
    nodes : array_like, shape (N, 2)
        Node coordinates.
    triangles : array_like, shape (T, 3)
        Node indices of the elements.

    Returns
    -------
    numpy.ndarray
        ``(T, 3, 3)`` maps ``M_e``.
    """
    p = np.asarray(nodes, dtype=np.float64)[np.asarray(triangles)]  # (T, 3, 2)
    A = np.ones((len(p), 3, 3))
    A[:, 0, :] = p[:, :, 0]
    A[:, 1, :] = p[:, :, 1]
    return np.linalg.inv(A)


@nb.njit(cache=True)
def _best_in(maps, cand, x, y):
    """Among elements ``cand``, the one whose smallest barycentric coordinate of ``(x, y)``
    is largest: ``(element, that coordinate, λ (3,))``; ``(-1, -inf, 0)`` for no candidates."""
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


@nb.njit(cache=True)
def _locate_batch(maps, start, items, lower, size, cells, points, tol):
    n = points.shape[0]
    elem = np.full(n, -1, dtype=np.int64)
    lam = np.zeros((n, 3))
    for p in range(n):
        x, y = points[p, 0], points[p, 1]
        fi = math.floor((x - lower[0]) / size[0])
        fj = math.floor((y - lower[1]) / size[1])
        # compare as floats: int() of a huge or infinite float is undefined
        if not (-1.0 <= fi <= cells and -1.0 <= fj <= cells):
            continue
        i = min(max(int(fi), 0), cells - 1)
        j = min(max(int(fj), 0), cells - 1)
        c = i * cells + j
        e, w, lm = _best_in(maps, items[start[c] : start[c + 1]], x, y)
        if e >= 0 and w >= -tol:
            elem[p] = e
            lam[p] = lm
    return elem, lam


class TriangleLocator:
    """Point location in a triangle mesh through a uniform grid (a few µs per query).

    Each of the ``cells x cells`` grid cells over the nodes' bounding box lists the
    elements whose bounding box meets it (CSR arrays ``start``, ``items``); a query
    evaluates the barycentric coordinates ``λ = M_e [x, y, 1]`` of those elements only and
    keeps the one whose smallest coordinate is largest. The point is in the mesh when that
    coordinate is ``>= -tol`` (closed convention; a point on an edge shared by two
    elements gets one of them, and either gives the same P1 interpolant). Points within
    one cell outside the bounding box are tested against the nearest cell, so the
    tolerance works on the mesh boundary too.

    ``maps``: the elements' ``(T, 3, 3)`` barycentric maps when already computed
    (``TissueMesh.barycentric_maps``).
    """

    def __init__(
        self,
        nodes,
        triangles,
        cells: int | None = None,
        tol: float = BARYCENTRIC_TOL,
        maps=None,
    ):
        nodes = np.asarray(nodes, dtype=np.float64)
        triangles = np.asarray(triangles, dtype=np.int64)
        n_tri = len(triangles)
        if cells is None:
            cells = max(2, int(np.sqrt(n_tri / 2.0)))
        self.cells = int(cells)
        self.tol = float(tol)
        self.lower = nodes.min(0)
        upper = nodes.max(0)
        self.size = np.maximum((upper - self.lower) / self.cells, 1e-300)
        self.maps = np.ascontiguousarray(
            barycentric_maps(nodes, triangles) if maps is None else maps, dtype=np.float64
        )
        p = nodes[triangles]
        lo = (np.floor((p.min(1) - self.lower) / self.size - 1e-9).astype(np.int64)).clip(
            0, self.cells - 1
        )
        hi = (np.floor((p.max(1) - self.lower) / self.size + 1e-9).astype(np.int64)).clip(
            0, self.cells - 1
        )
        ny = hi[:, 1] - lo[:, 1] + 1
        count = (hi[:, 0] - lo[:, 0] + 1) * ny
        elem = np.repeat(np.arange(n_tri, dtype=np.int64), count)
        k = np.arange(len(elem), dtype=np.int64) - np.repeat(np.cumsum(count) - count, count)
        cell = (lo[elem, 0] + k // ny[elem]) * self.cells + lo[elem, 1] + k % ny[elem]
        order = np.argsort(cell, kind="stable")  # ascending element index within a cell
        self.items = elem[order]
        self.start = np.searchsorted(cell[order], np.arange(self.cells * self.cells + 1))
        # one view per cell for the scalar path (indexing a list is cheaper than slicing)
        self._cand = [
            self.items[self.start[c] : self.start[c + 1]] for c in range(self.cells * self.cells)
        ]

    def locate(self, point) -> tuple[int, np.ndarray | None]:
        """``(element, λ (3,))`` of one ``point (2,)``, or ``(-1, None)`` outside the mesh.

        Parameters
        ----------
        point : array_like, shape (2,)
            The query point.

        Returns
        -------
        element : int
            The containing element, ``-1`` outside.
        weights : numpy.ndarray or None
            ``(3,)`` barycentric coordinates ``λ``, None outside.
        """
        x, y = float(point[0]), float(point[1])
        fi = math.floor((x - self.lower[0]) / self.size[0])
        fj = math.floor((y - self.lower[1]) / self.size[1])
        n = self.cells
        if not (-1 <= fi <= n and -1 <= fj <= n):
            return -1, None
        c = min(max(fi, 0), n - 1) * n + min(max(fj, 0), n - 1)
        e, worst, lam = _best_in(self.maps, self._cand[c], x, y)
        if e < 0 or worst < -self.tol:
            return -1, None
        return int(e), lam

    def locate_points(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Containing element ``(P,)`` (``-1`` outside) and barycentric weights ``(P, 3)``
        (zeros outside) of ``points (P, 2)``.

        Parameters
        ----------
        points : array_like, shape (P, 2)
            Query points.

        Returns
        -------
        elements : numpy.ndarray
            ``(P,)`` int64, ``-1`` outside.
        weights : numpy.ndarray
            ``(P, 3)`` barycentric coordinates, zeros outside.
        """
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
        return _locate_batch(
            self.maps, self.start, self.items, self.lower, self.size, self.cells, pts, self.tol
        )
