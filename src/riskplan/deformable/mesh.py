"""Triangle meshes of planar tissue (paper section V: a 2-D deformable body meshed with
a given number of elements, 50-1000 in the mesh-count uncertainty case).

:func:`mesh_polygon` meshes a simple polygon with the ``triangle`` package (Shewchuk's
Triangle) and searches the maximum-area constraint by bisection so the mesh has the
requested number of triangles. Polygon corners and any ``keep_points`` (fixed points,
load points, embedded obstacles) are mesh nodes.

:class:`TissueMesh` is the frozen value every FEM routine takes; constructing one
validates it (no inverted or degenerate triangles, no unused nodes) and caches what other
modules derive from the reference mesh as its own read-only cached properties.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from riskplan._validation import as_array, as_cells
from riskplan.deformable import elements
from riskplan.deformable.elements import boundary_edges, signed_areas
from riskplan.errors import InvalidInputError, require
from riskplan.geometry2d import (
    TriangleLocator,
    check_simple_polygon,
    closest_points_on_segments,
    points_in_polygon,
    polygon_area,
    polygon_segments,
    rectangle_polygon,
)

#: Relative area (w.r.t. the bounding-box area) below which a triangle is degenerate.
DEGENERATE_RTOL = 1e-12

#: Minimum angle (degrees) passed to Triangle's quality switch ``q``.
MIN_ANGLE_DEG = 30.0


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class TissueMesh:
    """A 2-D P1 triangle mesh (reference configuration), validated on construction.

    Attributes
    ----------
    nodes:
        ``(N, 2)`` float64 node coordinates (any consistent length unit).
    triangles:
        ``(T, 3)`` int64 node indices, counter-clockwise.
    vertex_nodes:
        ``(n,)`` node index of each polygon vertex the mesh was made from (empty if the
        mesh was given directly).
    kept_nodes:
        ``(k,)`` node index of each ``keep_points`` entry of :func:`mesh_polygon`.

    Raises :class:`InvalidInputError` for inverted (clockwise) or degenerate triangles
    (naming them), out-of-range indices, or nodes used by no triangle.

    Derived arrays are computed on first use and kept (read-only): ``areas``,
    ``boundary_edges``, ``shape_gradients``, ``barycentric_maps``, ``locator``.
    """

    nodes: np.ndarray
    triangles: np.ndarray
    vertex_nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    kept_nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self):
        nodes = as_array(self.nodes, "nodes", shape=(None, 2))
        tri = as_cells(self.triangles, "triangles", len(nodes), 3, "triangle")
        area = signed_areas(nodes, tri)
        span = np.ptp(nodes, axis=0)
        tol = DEGENERATE_RTOL * float(span[0] * span[1] + np.finfo(float).tiny)
        bad_inv = np.flatnonzero(area < -tol)
        bad_deg = np.flatnonzero(np.abs(area) <= tol)
        if bad_inv.size:
            raise InvalidInputError(
                f"triangles: {bad_inv.size} inverted (clockwise) triangles, e.g. {bad_inv[:10].tolist()}"
            )
        if bad_deg.size:
            raise InvalidInputError(
                f"triangles: {bad_deg.size} degenerate (zero-area) triangles, e.g. {bad_deg[:10].tolist()}"
            )
        object.__setattr__(self, "nodes", _readonly(nodes))
        object.__setattr__(self, "triangles", _readonly(tri))
        for name in ("vertex_nodes", "kept_nodes"):
            v = np.asarray(getattr(self, name), dtype=np.int64).reshape(-1)
            if v.size and (v.min() < 0 or v.max() >= len(nodes)):
                raise InvalidInputError(f"{name}: node indices out of range")
            object.__setattr__(self, name, _readonly(v))
        object.__setattr__(self, "_areas", _readonly(area))

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.shape[0])

    @property
    def n_elements(self) -> int:
        return int(self.triangles.shape[0])

    @property
    def areas(self) -> np.ndarray:
        """``(T,)`` element areas (positive)."""
        return self._areas

    @property
    def area(self) -> float:
        return float(self._areas.sum())

    @cached_property
    def boundary_edges(self) -> np.ndarray:
        """``(E, 2)`` boundary edges, counter-clockwise around the body."""
        return _readonly(boundary_edges(self.triangles))

    @cached_property
    def shape_gradients(self) -> np.ndarray:
        """``(T, 3, 2)`` reference gradients ``∇_X N_a`` of the P1 shape functions."""
        return _readonly(elements.shape_gradients(self.nodes, self.triangles))

    @cached_property
    def barycentric_maps(self) -> np.ndarray:
        """``(T, 3, 3)`` maps ``λ = M_e @ [x, y, 1]`` from points to barycentric weights."""
        return _readonly(elements.barycentric_maps(self.nodes, self.triangles))

    @cached_property
    def locator(self) -> TriangleLocator:
        """Grid point locator of the elements (:class:`riskplan.geometry2d.TriangleLocator`,
        on the cached ``barycentric_maps``)."""
        return TriangleLocator(self.nodes, self.triangles, maps=self.barycentric_maps)

    @property
    def boundary_nodes(self) -> np.ndarray:
        """``(B,)`` sorted indices of nodes on the boundary."""
        return np.unique(self.boundary_edges)

    @property
    def h(self) -> float:
        """Mesh size: the longest edge length."""
        p = self.nodes[self.triangles]
        e = p - np.roll(p, 1, axis=1)
        return float(np.sqrt((e**2).sum(-1)).max())

    def nodes_near(self, points, tol: float = 1e-9) -> np.ndarray:
        """Index of the node closest to each point.

        Parameters
        ----------
        points : array_like, (P, 2)
            Reference positions.
        tol : float
            Largest accepted distance; a point farther from every node raises
            :class:`InvalidInputError`.

        Returns
        -------
        numpy.ndarray of int, (P,)
        """
        pts = as_array(points, "points", last_dim=2).reshape(-1, 2)
        d2 = ((pts[:, None, :] - self.nodes[None]) ** 2).sum(-1)
        idx = d2.argmin(1)
        far = np.sqrt(d2[np.arange(len(pts)), idx]) > tol
        if np.any(far):
            raise InvalidInputError(
                f"points: {pts[far][:3].tolist()} are not mesh nodes (tol {tol:g})"
            )
        return idx

    def to_skfem(self):
        """The same mesh as a ``skfem.MeshTri``.

        Returns
        -------
        skfem.MeshTri
            The mesh.
        """
        skfem = require("skfem", "fem")
        return skfem.MeshTri(
            np.ascontiguousarray(self.nodes.T), np.ascontiguousarray(self.triangles.T)
        )

    def __repr__(self) -> str:
        return f"TissueMesh(n_nodes={self.n_nodes}, n_elements={self.n_elements}, area={self.area:.6g})"


# --------------------------------------------------------------------------------------
# polygon meshing


def _build_pslg(poly: np.ndarray, keep: np.ndarray):
    """Vertices/segments for Triangle: keep points within ``1e-9`` of the polygon's extent
    of a vertex are that vertex, within it of an edge split that edge, the rest must lie
    inside. Returns (vertices, segments, index of each keep point)."""
    scale = float(np.ptp(poly, axis=0).max())
    tol = 1e-9 * scale
    n = len(poly)
    on_edge: dict[int, list[tuple[float, int]]] = {}
    keep_index = np.empty(len(keep), dtype=np.int64)
    verts = [v for v in poly]
    interior = []
    # distance of each keep point to the boundary: the edge-snapping rule of the mesher
    # is "within tol of an edge" (a named tolerance, not the exact contact rule)
    dist, _, edge = closest_points_on_segments(polygon_segments(poly), keep)
    for k, p in enumerate(keep):
        dv = np.sqrt(((poly - p) ** 2).sum(1))
        if dv.min() <= tol:
            keep_index[k] = int(dv.argmin())
        elif dist[k] <= tol:  # on edge i, away from its ends: splits it at t in (0, 1)
            i = int(edge[k])
            a, b = poly[i], poly[(i + 1) % n]
            ab = b - a
            on_edge.setdefault(i, []).append((float(np.dot(p - a, ab) / np.dot(ab, ab)), k))
        else:
            interior.append(k)
    if interior:
        inside = points_in_polygon(keep[interior], poly)
        if not np.all(inside):
            bad = keep[np.asarray(interior)[~inside]]
            raise InvalidInputError(f"keep_points: {bad[:3].tolist()} lie outside the polygon")
    # boundary chain with the on-edge keep points inserted in order
    chain = []
    for i in range(n):
        chain.append(i)
        for _t, k in sorted(on_edge.get(i, [])):
            keep_index[k] = len(verts)
            verts.append(keep[k])
            chain.append(keep_index[k])
    segs = np.array(
        [[chain[j], chain[(j + 1) % len(chain)]] for j in range(len(chain))], dtype=np.int32
    )
    for k in interior:
        keep_index[k] = len(verts)
        verts.append(keep[k])
    return np.asarray(verts, dtype=np.float64), segs, keep_index


def _triangulate(tri_mod, pslg: dict, max_area: float, min_angle: float):
    # Triangle does not parse exponents: write the area in fixed notation, ~15 digits
    digits = max(1, 15 - math.floor(math.log10(max_area)))
    return tri_mod.triangulate(pslg, f"pq{min_angle:.4f}Qa{max_area:.{digits}f}")


def _split_boundary_edges(nodes: np.ndarray, tris: np.ndarray, k: int):
    """Bisect the ``k`` longest boundary edges one after another (each adds one triangle)."""
    nodes, tris = nodes.copy(), tris.copy()
    for _ in range(k):
        be = boundary_edges(tris)
        length = np.linalg.norm(nodes[be[:, 1]] - nodes[be[:, 0]], axis=1)
        a, b = be[int(length.argmax())]
        # the triangle holding the directed edge a->b
        t = int(np.flatnonzero(((tris == a) & (np.roll(tris, -1, axis=1) == b)).any(1))[0])
        j = int(np.flatnonzero(tris[t] == a)[0])
        c = tris[t, (j + 2) % 3]
        m = len(nodes)
        nodes = np.vstack([nodes, 0.5 * (nodes[a] + nodes[b])])
        tris[t] = (a, m, c)
        tris = np.vstack([tris, [m, b, c]])
    return nodes, tris


def mesh_polygon(
    vertices,
    n_elements: int,
    keep_points=None,
    *,
    min_angle: float = MIN_ANGLE_DEG,
    max_iter: int = 60,
) -> TissueMesh:
    """Quality triangle mesh of a simple polygon with (as close as possible to) ``n_elements``
    triangles.

    Parameters
    ----------
    vertices : array_like, (n, 2)
        Polygon corners in order (either orientation); they become mesh nodes.
    n_elements : int
        Requested triangle count (the paper's range is 50-1000; anything from the
        coarsest constrained triangulation up to 200 000 is accepted).
    keep_points : array_like, (k, 2), optional
        Points that must be mesh nodes (inside the polygon or on its
        boundary); their node indices are ``mesh.kept_nodes``.
    min_angle : float
        Minimum angle in degrees for Triangle's quality refinement (0-33).
    max_iter : int
        Bisection steps on the maximum triangle area.

    Returns
    -------
    TissueMesh
        ``n_elements`` triangles (see Notes), the corners and ``keep_points`` among its nodes.

    Notes
    -----
    Method: Triangle with switches ``p q<min_angle> a<A>``; the element count decreases
    (not strictly) as the maximum area ``A`` grows, so ``A`` is bisected in log scale and
    the largest count not above the request is kept. For a triangulation
    ``T = 2V - B - 2`` (``B`` boundary nodes), so the count can jump by 2 across the
    request; the remaining one or few triangles are made by bisecting the longest
    boundary edges (each adds exactly one triangle). The count is therefore exact for
    every request at or above the coarsest quality mesh of the polygon; below it an
    :class:`InvalidInputError` is raised.
    """
    tri_mod = require("triangle", "fem")
    vertices = as_array(vertices, "vertices", shape=(None, 2))
    poly = check_simple_polygon(vertices, "vertices")
    flipped = polygon_area(vertices) < 0
    if not isinstance(n_elements, (int, np.integer)) or isinstance(n_elements, bool):
        raise InvalidInputError(f"n_elements: expected an int, got {type(n_elements).__name__}")
    n_elements = int(n_elements)
    if not 1 <= n_elements <= 200_000:
        raise InvalidInputError(f"n_elements: expected 1 <= n_elements <= 200000, got {n_elements}")
    if not 0.0 <= min_angle <= 33.0:
        raise InvalidInputError(
            f"min_angle: expected 0 <= min_angle <= 33 degrees, got {min_angle}"
        )
    keep = (
        np.zeros((0, 2))
        if keep_points is None
        else as_array(keep_points, "keep_points", last_dim=2).reshape(-1, 2)
    )
    verts, segs, keep_index = _build_pslg(poly, keep)
    pslg = {"vertices": verts, "segments": segs}
    area = polygon_area(poly)

    cache: dict[float, dict] = {}

    def run(a: float):
        if a not in cache:
            cache[a] = _triangulate(tri_mod, pslg, a, min_angle)
        return cache[a]

    below = None  # (count, area): the largest count <= n_elements seen

    def consider(a: float) -> int:
        nonlocal below
        c = int(run(a)["triangles"].shape[0])
        if c <= n_elements and (below is None or c > below[0]):
            below = (c, a)
        return c

    a_coarse = area * 10.0
    coarsest = consider(a_coarse)
    if n_elements < coarsest:
        raise InvalidInputError(
            f"n_elements: {n_elements} is below the coarsest quality mesh of this polygon ({coarsest} triangles)"
        )
    lo, hi = math.log(a_coarse), math.log(area / n_elements) - 1.0  # count(lo) <= n < count(hi)
    while consider(math.exp(hi)) <= n_elements and below[0] != n_elements:
        hi -= 1.0
    for _ in range(max_iter):
        if below[0] == n_elements or abs(hi - lo) < 1e-9:
            break
        mid = 0.5 * (lo + hi)
        if consider(math.exp(mid)) <= n_elements:
            lo = mid
        else:
            hi = mid
    out = run(below[1])
    nodes = np.asarray(out["vertices"], dtype=np.float64)
    tris = np.asarray(out["triangles"], dtype=np.int64)
    area_t = signed_areas(nodes, tris)
    tris[area_t < 0] = tris[area_t < 0][:, [0, 2, 1]]
    # T = 2V - B - 2: a count step of 2 can straddle the target; each bisected boundary
    # edge adds one node on the boundary and exactly one triangle.
    nodes, tris = _split_boundary_edges(nodes, tris, n_elements - below[0])
    return TissueMesh(
        nodes=nodes,
        triangles=tris,
        vertex_nodes=np.arange(len(poly), dtype=np.int64)[::-1]
        if flipped
        else np.arange(len(poly), dtype=np.int64),
        kept_nodes=keep_index,
    )


def rectangle(width: float = 1.0, height: float = 1.0, origin=(0.0, 0.0)) -> np.ndarray:
    """Counter-clockwise corners of an axis-aligned rectangle.

    Parameters
    ----------
    width, height : float
        Side lengths.
    origin : array_like, (2,)
        Lower-left corner.

    Returns
    -------
    numpy.ndarray, (4, 2)
    """
    x0, y0 = float(origin[0]), float(origin[1])
    return rectangle_polygon((x0, y0), (x0 + width, y0 + height))
