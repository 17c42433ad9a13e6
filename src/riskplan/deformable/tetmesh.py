"""Tetrahedral meshes of 3-D tissue: the P1 tetrahedron's geometry, mesh validation with a
quality check, and meshes of a block or of a closed surface (an organ's STL).

Meshers (licences, because the defaults must stay permissive):

* :func:`tet_block` — scikit-fem's own ``MeshTet.init_tensor`` (BSD-3-Clause): a tensor
  grid of ``nx × ny × nz`` hexahedra, each split into 6 tetrahedra (Kuhn split), so the
  element count is ``6 nx ny nz``; the grid is chosen to come closest to a requested count.
* :func:`tet_fill_surface` — a closed triangle surface filled with the same tensor lattice,
  keeping the tetrahedra whose centroid ``trimesh`` (MIT) finds inside the surface: a
  staircase approximation of the organ of one lattice spacing, no external mesher needed.
  Boundary-conforming meshes of a surface can come from TetGen (``tetgen``, AGPL-3.0) or
  gmsh (GPL-2.0+) as optional extras (see ``docs/scenarios.md``); their output is taken
  through :class:`TetMesh` like any other mesh, so it passes the same quality check.

:class:`TetMesh` is the frozen value every 3-D FEM routine takes. Constructing one checks
indices, positive orientation (an inverted tetrahedron, volume < 0, is named) and element
quality (slivers are named with their quality), and caches the derived arrays.

Element quality is the volume-length ratio

    q = 6√2 V / ℓ_rms³,     ℓ_rms² = (1/6) Σ_edges ℓ²,

1 for the regular tetrahedron, 0 for a flat one (a sliver has four well-separated nodes and
q → 0). The P1 stiffness' condition number grows like ``1/q²``; a mesh with an element below
``min_quality`` (default :data:`MIN_QUALITY`) is refused.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from riskplan._validation import as_array, as_cells
from riskplan.errors import InvalidInputError, require

#: Default least element quality q (volume-length ratio) a mesh may have. The Kuhn split of a
#: cube has q = 0.72 and skfem's refined meshes stay above 0.5; a Delaunay sliver has
#: q < 0.01, where the element stiffness is ~10⁴ times worse conditioned than a regular
#: tetrahedron's (1/q²) — refused as bad input rather than solved inaccurately.
MIN_QUALITY = 0.02

#: Largest element count the builders accept (a 3-D direct factorisation's fill grows fast).
MAX_ELEMENTS = 200_000

#: Node pairs of the six edges of a tetrahedron.
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])

#: Names of the six faces of a block accepted by :meth:`TetMesh.face_nodes`.
FACES = ("x-", "x+", "y-", "y+", "z-", "z+")


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


# --------------------------------------------------------------------------------------
# P1 tetrahedron geometry (pure array functions)


def edge_matrices(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """``D (T, 3, 3)`` with columns ``x₁ − x₀, x₂ − x₀, x₃ − x₀`` of each tetrahedron."""
    p = nodes[tets]
    return np.swapaxes(p[:, 1:] - p[:, :1], 1, 2)


def signed_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes ``V = det(D)/6`` ``(T,)``; > 0 for positively oriented tetrahedra."""
    return np.linalg.det(edge_matrices(nodes, tets)) / 6.0


def quality(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Volume-length ratio ``q = 6√2 V / ℓ_rms³`` ``(T,)`` (signed: < 0 when inverted)."""
    p = nodes[tets]
    e = p[:, TET_EDGES[:, 1]] - p[:, TET_EDGES[:, 0]]
    lrms = np.sqrt((e**2).sum(-1).mean(1))
    return 6.0 * np.sqrt(2.0) * signed_volumes(nodes, tets) / np.maximum(lrms, 1e-300) ** 3


def shape_gradients(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """``(T, 4, 3)`` reference gradients ``∇_X N_a`` of the P1 shape functions:
    rows 1..3 are the rows of ``D⁻¹``, ``∇N₀ = −(∇N₁ + ∇N₂ + ∇N₃)``."""
    Dinv = np.linalg.inv(edge_matrices(nodes, tets))
    return np.concatenate([-Dinv.sum(1, keepdims=True), Dinv], axis=1)


def barycentric_maps(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """``(T, 4, 4)`` maps with ``λ = M_e @ [x, y, z, 1]`` (barycentric weights of a point)."""
    G = shape_gradients(nodes, tets)
    x0 = nodes[tets[:, 0]]
    M = np.empty((len(tets), 4, 4))
    M[:, :, :3] = G
    # λ_a(x) = δ_a0 + ∇N_a · (x − x₀)
    M[:, :, 3] = -np.einsum("tak,tk->ta", G, x0)
    M[:, 0, 3] += 1.0
    return M


@dataclass(frozen=True, eq=False)
class TetMesh:
    """A P1 tetrahedral mesh (reference configuration), validated on construction.

    Attributes
    ----------
    nodes:
        ``(N, 3)`` float64 node coordinates (any consistent length unit).
    tets:
        ``(T, 4)`` int64 node indices, positively oriented (``det[x₁−x₀, x₂−x₀, x₃−x₀] > 0``).
    min_quality:
        The least element quality accepted (see module docstring).

    Raises :class:`InvalidInputError` for out-of-range indices, unused nodes, inverted
    (negative volume) or degenerate elements, and elements of quality below
    ``min_quality`` — naming the worst element and its quality.

    Derived arrays (read-only, computed on first use): ``volumes``, ``qualities``,
    ``shape_gradients``, ``barycentric_maps``, ``centroids``, ``boundary_faces``.
    """

    nodes: np.ndarray
    tets: np.ndarray
    min_quality: float = MIN_QUALITY

    def __post_init__(self):
        nodes = as_array(self.nodes, "nodes", shape=(None, 3))
        t = as_cells(self.tets, "tets", len(nodes), 4, "tetrahedron")
        mq = float(self.min_quality)
        if not 0.0 <= mq < 1.0:
            raise InvalidInputError(f"min_quality: expected 0 <= min_quality < 1, got {mq!r}")
        q = quality(nodes, t)
        vol = signed_volumes(nodes, t)
        inverted = np.flatnonzero(q < 0.0)
        if inverted.size:
            w = int(inverted[np.argmin(q[inverted])])
            raise InvalidInputError(
                f"tets: {inverted.size} inverted element(s) (negative volume), worst element "
                f"{w} with quality {q[w]:.3g} (volume {vol[w]:.3g}); e.g. {inverted[:10].tolist()}"
            )
        bad = np.flatnonzero(q < mq) if mq > 0 else np.flatnonzero(q <= 0.0)
        if bad.size:
            w = int(bad[np.argmin(q[bad])])
            raise InvalidInputError(
                f"tets: {bad.size} element(s) below the quality bound {mq:g} (slivers or flat "
                f"elements), worst element {w} with quality {q[w]:.3g} (1 = regular "
                f"tetrahedron); e.g. {bad[:10].tolist()}"
            )
        object.__setattr__(self, "nodes", _readonly(nodes))
        object.__setattr__(self, "tets", _readonly(t))
        object.__setattr__(self, "min_quality", mq)
        object.__setattr__(self, "_volumes", _readonly(vol))
        object.__setattr__(self, "_quality", _readonly(q))

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.shape[0])

    @property
    def n_elements(self) -> int:
        return int(self.tets.shape[0])

    @property
    def volumes(self) -> np.ndarray:
        """``(T,)`` element volumes (positive)."""
        return self._volumes

    @property
    def volume(self) -> float:
        return float(self._volumes.sum())

    @property
    def qualities(self) -> np.ndarray:
        """``(T,)`` element qualities ``q ∈ (0, 1]`` (module docstring)."""
        return self._quality

    @cached_property
    def shape_gradients(self) -> np.ndarray:
        """``(T, 4, 3)`` reference gradients of the P1 shape functions."""
        return _readonly(shape_gradients(self.nodes, self.tets))

    @cached_property
    def barycentric_maps(self) -> np.ndarray:
        """``(T, 4, 4)`` maps ``λ = M_e @ [x, y, z, 1]``."""
        return _readonly(barycentric_maps(self.nodes, self.tets))

    @cached_property
    def centroids(self) -> np.ndarray:
        """``(T, 3)`` element centroids."""
        return _readonly(self.nodes[self.tets].mean(1))

    @cached_property
    def boundary_faces(self) -> np.ndarray:
        """``(B, 3)`` triangles on the boundary (faces of exactly one tetrahedron),
        oriented with the outward normal by the right-hand rule."""
        t = self.tets
        # faces opposite node 0..3, each ordered so its normal points away from that node
        f = np.concatenate([t[:, [1, 2, 3]], t[:, [0, 3, 2]], t[:, [0, 1, 3]], t[:, [0, 2, 1]]])
        key = np.sort(f, axis=1)
        _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        return _readonly(f[counts[inv.ravel()] == 1])

    @property
    def boundary_nodes(self) -> np.ndarray:
        """``(B,)`` sorted indices of the nodes on the boundary."""
        return np.unique(self.boundary_faces)

    @property
    def bounds(self) -> np.ndarray:
        """``(2, 3)``: the lower and upper corner of the bounding box."""
        return np.stack([self.nodes.min(0), self.nodes.max(0)])

    @property
    def h(self) -> float:
        """Mesh size: the longest edge length."""
        p = self.nodes[self.tets]
        e = p[:, TET_EDGES[:, 1]] - p[:, TET_EDGES[:, 0]]
        return float(np.sqrt((e**2).sum(-1)).max())

    def face_nodes(self, face: str, tol: float = 1e-9) -> np.ndarray:
        """Nodes on one face of the bounding box.

        Parameters
        ----------
        face : str
            One of :data:`FACES` (``"z-"``: the lowest ``z``).
        tol : float
            Distance from the face, relative to the box's largest extent.

        Returns
        -------
        ndarray of int, shape (F,)
            Sorted node indices.
        """
        if face not in FACES:
            raise InvalidInputError(f"face: expected one of {FACES}, got {face!r}")
        k = "xyz".index(face[0])
        lo, hi = self.bounds[:, k]
        value = lo if face[1] == "-" else hi
        span = float(np.ptp(self.nodes, axis=0).max())
        return np.flatnonzero(np.abs(self.nodes[:, k] - value) <= tol * span)

    def nodes_in_box(self, lower, upper) -> np.ndarray:
        """Nodes inside a closed axis-aligned box.

        Parameters
        ----------
        lower, upper : array_like, shape (3,)
            Opposite corners of the box.

        Returns
        -------
        ndarray of int, shape (F,)
            Sorted node indices.
        """
        lo = as_array(lower, "lower", shape=(3,))
        hi = as_array(upper, "upper", shape=(3,))
        return np.flatnonzero(np.all((self.nodes >= lo) & (self.nodes <= hi), axis=1))

    def to_skfem(self):
        """The same mesh as a ``skfem.MeshTet`` (same node and element order).

        Returns
        -------
        skfem.MeshTet
            The mesh.
        """
        skfem = require("skfem", "fem")
        return skfem.MeshTet(np.ascontiguousarray(self.nodes.T), np.ascontiguousarray(self.tets.T))

    def __repr__(self) -> str:
        return (
            f"TetMesh(n_nodes={self.n_nodes}, n_elements={self.n_elements}, "
            f"volume={self.volume:.6g}, min_quality={float(self._quality.min()):.3g})"
        )


# --------------------------------------------------------------------------------------
# builders


def _count(n_elements, name="n_elements") -> int:
    if isinstance(n_elements, (bool, np.bool_)) or not isinstance(n_elements, (int, np.integer)):
        raise InvalidInputError(f"{name}: expected an int, got {type(n_elements).__name__}")
    n = int(n_elements)
    if not 6 <= n <= MAX_ELEMENTS:
        raise InvalidInputError(f"{name}: expected 6 <= {name} <= {MAX_ELEMENTS}, got {n}")
    return n


def _orient(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Swap two nodes of the negatively oriented tetrahedra."""
    tets = tets.copy()
    neg = signed_volumes(nodes, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    return tets


def grid_shape(size, n_elements: int) -> tuple[int, int, int]:
    """``(nx, ny, nz)`` hexahedra per side of a block of ``size (3,)`` whose Kuhn split
    (``6 nx ny nz`` tetrahedra) comes closest to ``n_elements``, among grids whose cells
    have aspect ratio at most 2 (ties: the more cubic cells)."""
    size = np.asarray(size, dtype=np.float64)
    target = n_elements / 6.0
    h0 = (float(np.prod(size)) / target) ** (1.0 / 3.0)
    best = None
    base = np.maximum(1, np.round(size / h0)).astype(int)
    ranges = [range(max(1, b - 3), b + 4) for b in base]
    for nx, ny, nz in itertools.product(*ranges):
        cell = size / np.array([nx, ny, nz])
        aspect = float(cell.max() / cell.min())
        if aspect > 2.0:
            continue
        key = (abs(6 * nx * ny * nz - n_elements), aspect)
        if best is None or key < best[0]:
            best = (key, (nx, ny, nz))
    if best is None:  # a very elongated block: the nearest integer grid
        return tuple(int(b) for b in base)
    return best[1]


def tet_block(
    size=(1.0, 1.0, 1.0),
    n_elements: int = 5000,
    origin=(0.0, 0.0, 0.0),
    *,
    shape: tuple[int, int, int] | None = None,
) -> TetMesh:
    """Tetrahedral mesh of the axis-aligned block ``origin + [0, size]`` with about
    ``n_elements`` tetrahedra (scikit-fem ``MeshTet.init_tensor``, 6 per grid hexahedron).

    The count is ``6 nx ny nz`` for the grid of :func:`grid_shape` (or the given ``shape``):
    5000 requested on a unit cube gives 5040 elements. Every grid point is a node, so faces
    are exact planes (:meth:`TetMesh.face_nodes`).

    Parameters
    ----------
    size : array_like, shape (3,)
        Side lengths (> 0).
    n_elements : int
        Requested element count (6 to :data:`MAX_ELEMENTS`); ignored when ``shape`` is given.
    origin : array_like, shape (3,)
        Lower corner.
    shape : tuple of int, optional
        Grid cells ``(nx, ny, nz)``.

    Returns
    -------
    TetMesh
    """
    skfem = require("skfem", "fem")
    size_a = as_array(size, "size", shape=(3,))
    if np.any(size_a <= 0):
        raise InvalidInputError(f"size: expected positive side lengths, got {size_a.tolist()}")
    o = as_array(origin, "origin", shape=(3,))
    if shape is None:
        shape = grid_shape(size_a, _count(n_elements))
    nx, ny, nz = (int(s) for s in shape)
    if min(nx, ny, nz) < 1 or 6 * nx * ny * nz > MAX_ELEMENTS:
        raise InvalidInputError(f"shape: expected positive cells, at most {MAX_ELEMENTS} tets")
    axes = [o[k] + np.linspace(0.0, size_a[k], n + 1) for k, n in enumerate((nx, ny, nz))]
    m = skfem.MeshTet.init_tensor(*axes)
    nodes = np.ascontiguousarray(m.p.T, dtype=np.float64)
    return TetMesh(nodes, _orient(nodes, np.ascontiguousarray(m.t.T, dtype=np.int64)))


def _load_surface(surface):
    trimesh = require("trimesh", "mesh")
    if isinstance(surface, trimesh.Trimesh):
        mesh = surface
    else:
        try:
            mesh = trimesh.load(str(surface), force="mesh")
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise InvalidInputError(f"surface: cannot read {surface!r} ({exc})") from exc
    if not mesh.is_watertight:
        raise InvalidInputError(
            "surface: not a closed (watertight) surface; its inside is undefined"
        )
    return mesh


def _largest_component(tets: np.ndarray) -> np.ndarray:
    """The tetrahedra of the largest face-connected set (a lattice clipped by a surface can
    leave pieces joined to the body by an edge or a node only, which would hinge freely)."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    T = len(tets)
    faces = np.sort(
        np.concatenate(
            [tets[:, [1, 2, 3]], tets[:, [0, 2, 3]], tets[:, [0, 1, 3]], tets[:, [0, 1, 2]]]
        ),
        axis=1,
    )
    owner = np.tile(np.arange(T), 4)
    _, inv = np.unique(faces, axis=0, return_inverse=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    same = inv[order][1:] == inv[order][:-1]  # interior faces: two owners in a row
    a, b = owner[order][:-1][same], owner[order][1:][same]
    graph = sparse.coo_matrix((np.ones(len(a)), (a, b)), shape=(T, T))
    n, label = connected_components(graph, directed=False)
    if n == 1:
        return tets
    return tets[label == np.bincount(label).argmax()]


def tet_fill_surface(surface, n_elements: int = 5000, *, max_iter: int = 12) -> TetMesh:
    """Tetrahedral mesh of the inside of a closed triangle surface with about
    ``n_elements`` tetrahedra.

    Method: the Kuhn-split tensor lattice of the surface's bounding box (cubic cells of side
    ``h``), keeping the tetrahedra whose centroid lies inside the surface (``trimesh``
    ``contains``), then the largest face-connected set of them; ``h`` is bisected so the
    kept count comes close to the request (within a few percent; the count moves in steps of
    the lattice). The boundary is a staircase within one cell ``h`` of the surface.

    Parameters
    ----------
    surface : trimesh.Trimesh or path
        A closed (watertight) surface, or a file trimesh reads (e.g. an organ's STL).
    n_elements : int
        Requested element count.
    max_iter : int
        Lattice sizes tried at most.

    Returns
    -------
    TetMesh

    Raises
    ------
    InvalidInputError
        An open or unreadable surface, or a request too small to leave any element.
    """
    n = _count(n_elements)
    surf = _load_surface(surface)
    skfem = require("skfem", "fem")
    lo, hi = np.asarray(surf.bounds[0], float), np.asarray(surf.bounds[1], float)
    size = hi - lo
    vol = abs(float(surf.volume))

    def build(h: float):
        counts = np.maximum(1, np.ceil(size / h - 1e-9).astype(int))
        ext = counts * h
        start = lo - 0.5 * (ext - size)
        axes = [start[k] + h * np.arange(counts[k] + 1) for k in range(3)]
        m = skfem.MeshTet.init_tensor(*axes)
        p = m.p.T
        t = m.t.T
        keep = surf.contains(p[t].mean(1))
        return p, t[keep]

    h = (6.0 * vol / n) ** (1.0 / 3.0)  # 6 tets per h³ cell
    best = None
    lo_h, hi_h = None, None
    for _ in range(max_iter):
        p, t = build(h)
        c = len(t)
        if c and (best is None or abs(c - n) < abs(best[0] - n)):
            best = (c, p, t)
        if c and abs(c - n) <= 0.02 * n:
            break
        if c > n:
            lo_h = h
        else:
            hi_h = h
        h = 0.5 * (lo_h + hi_h) if lo_h and hi_h else h * (c / n if c else 0.5) ** (1.0 / 3.0)
    if best is None:
        raise InvalidInputError(
            f"n_elements: {n} leaves no tetrahedron inside the surface; request more"
        )
    _, p, t = best
    t = _largest_component(t)
    used = np.unique(t)
    remap = np.full(len(p), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    nodes = np.ascontiguousarray(p[used], dtype=np.float64)
    return TetMesh(nodes, _orient(nodes, remap[t]))
