"""Material points of a tetrahedral mesh: point location (k-d tree on element centroids,
then an exhaustive search; a compiled lookup in a regular grid's cell), barycentric
interpolators, spherical material-point sets (embedded obstacles and targets), and the
material-point queries of :class:`riskplan.deformable.TetTissue` (``TetMaterialPoints``,
its base class).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from riskplan._validation import as_array
from riskplan.deformable.material_points import Interpolator
from riskplan.deformable.tetassembly import deformation_gradients
from riskplan.deformable.tetmesh import TetMesh
from riskplan.errors import InvalidInputError

#: A point counts as inside an element when its smallest barycentric weight is >= -INSIDE_TOL.
INSIDE_TOL = 1e-10

#: Element centroids tried per point before the exhaustive search (nearest first).
LOCATE_CANDIDATES = 12

# --------------------------------------------------------------------------------------
# point location


def find_points(mesh: TetMesh, points: np.ndarray, k: int = LOCATE_CANDIDATES):
    """Containing element ``(P,)`` and barycentric weights ``(P, 4)`` of ``points (P, 3)``;
    element ``-1`` (weights of the best candidate) for points outside the mesh.

    The ``k`` elements with the nearest centroids (a k-d tree) are tried first, then the
    ``4k`` nearest; points inside none of them are searched exhaustively, so whether a point
    is found does not depend on ``k``. Picks, among the elements tried, the one whose
    smallest barycentric weight is largest (a point on a shared face may take either
    element; interpolated values agree).
    """
    from scipy.spatial import cKDTree

    maps = mesh.barycentric_maps
    P = len(points)
    elem = np.full(P, -1, dtype=np.int64)
    lam = np.zeros((P, 4))
    if P == 0:
        return elem, lam
    tree = mesh.__dict__.get("_centroid_tree")
    if tree is None:
        tree = cKDTree(mesh.centroids)
        object.__setattr__(mesh, "_centroid_tree", tree)
    todo = np.arange(P)
    # nearest centroids first, then a wider ring for the few points whose element's centroid
    # is not among the k nearest (slender elements), then the exhaustive search
    for kk in (min(k, mesh.n_elements), min(4 * k, mesh.n_elements)):
        if todo.size == 0:
            break
        q = points[todo]
        _, cand = tree.query(q, k=kk)
        cand = np.asarray(cand).reshape(len(todo), kk)
        b = np.einsum("pkij,pj->pki", maps[cand][:, :, :, :3], q) + maps[cand][:, :, :, 3]
        worst = b.min(axis=2)
        j = worst.argmax(axis=1)
        rows = np.arange(len(todo))
        ok = worst[rows, j] >= -INSIDE_TOL
        elem[todo[ok]] = cand[rows[ok], j[ok]]
        lam[todo] = b[rows, j]
        todo = todo[~ok]
    for s in range(0, len(todo), 64):
        idx = todo[s : s + 64]
        bb = np.einsum("tij,pj->pti", maps[:, :, :3], points[idx]) + maps[None, :, :, 3]
        w = bb.min(axis=2)
        e = w.argmax(axis=1)
        r = np.arange(len(idx))
        inside = w[r, e] >= -INSIDE_TOL
        elem[idx] = np.where(inside, e, -1)
        lam[idx] = bb[r, e]
    return elem, lam


@nb.njit(cache=True)
def locate_in_grid(X, size, grid, cell_tets, cell_maps, tol):
    """The tetrahedron of a regular grid's cell holding ``X`` (a block split alike in every
    cell): among the cell's tetrahedra the one whose smallest barycentric weight is largest
    (the first on ties), if that weight is ``>= −tol``; compiled (a simulator's hot path).

    Parameters
    ----------
    X : numpy.ndarray, shape (3,)
        The point (outside ``[0, size]`` or NaN: element ``−1``).
    size : numpy.ndarray, shape (3,)
        The block's edge lengths.
    grid : numpy.ndarray, shape (3,)
        Cells per axis (int64).
    cell_tets : numpy.ndarray, shape (C, m)
        The tetrahedra of each cell (cells numbered ``(i nx_y + j) n_z + k``).
    cell_maps : numpy.ndarray, shape (C, m, 4, 4)
        Their barycentric maps (``TetMesh.barycentric_maps``).
    tol : float
        The inside tolerance (``INSIDE_TOL``).

    Returns
    -------
    element : int
        The tetrahedron, ``−1`` if the point lies outside the block or in none of the
        cell's tetrahedra (round-off).
    lam : numpy.ndarray, shape (4,)
        Its barycentric weights.
    """
    lam = np.zeros(4)
    c = 0
    for k in range(3):
        if not 0.0 <= X[k] <= size[k]:  # outside the block, or NaN
            return -1, lam
        i = min(int(X[k] * grid[k] / size[k]), grid[k] - 1)
        c = c * grid[k] + i
    best, jb = -np.inf, 0
    for j in range(cell_tets.shape[1]):
        w = np.inf
        for r in range(4):
            M = cell_maps[c, j, r]
            w = min(w, M[0] * X[0] + M[1] * X[1] + M[2] * X[2] + M[3])
        if w > best:
            best, jb = w, j
    for r in range(4):
        M = cell_maps[c, jb, r]
        lam[r] = M[0] * X[0] + M[1] * X[1] + M[2] * X[2] + M[3]
    if best < -tol:
        return -1, lam
    return cell_tets[c, jb], lam


def locate3d(mesh: TetMesh, points, name: str = "points") -> Interpolator:
    """An :class:`~riskplan.deformable.material_points.Interpolator` for material points ``(P, 3)``
    (or one ``(3,)``) of ``mesh``; raises :class:`InvalidInputError` naming the set
    (``name``: "target", "obstacle 2", ...) and the points outside the tissue."""
    pts = as_array(points, name, last_dim=3)
    if pts.ndim > 2:
        raise InvalidInputError(f"{name}: expected shape (P, 3) or (3,), got {pts.shape}")
    pts = np.ascontiguousarray(pts.reshape(-1, 3))
    elem, lam = find_points(mesh, pts)
    outside = np.flatnonzero(elem < 0)
    if outside.size:
        raise InvalidInputError(
            f"{name}: {outside.size} point(s) lie outside the tissue, e.g. index "
            f"{outside[:5].tolist()} at {pts[outside[:3]].tolist()}"
        )
    idx = mesh.tets[elem]
    for a in (pts, elem, lam, idx):
        a.setflags(write=False)
    return Interpolator(
        points=pts, elements=elem, node_index=idx, weights=lam, n_nodes=mesh.n_nodes
    )


def sphere_points(center, radius: float, n_points: int = 64) -> np.ndarray:
    """Material points of a spherical region (an embedded obstacle or target): its centre
    and ``n_points`` points on its surface (Fibonacci lattice, nearly uniform).

    Locate them with :meth:`TetTissue.interpolator`; their deformed positions follow the
    tissue.

    Parameters
    ----------
    center : array_like, shape (3,)
        Centre of the sphere (reference configuration).
    radius : float
        Radius (> 0).
    n_points : int
        Points on the surface (>= 4).

    Returns
    -------
    ndarray, shape (n_points + 1, 3)
        The centre first, then the surface points.
    """
    c = as_array(center, "center", shape=(3,))
    r = float(radius)
    if not (np.isfinite(r) and r > 0):
        raise InvalidInputError(f"radius: expected a finite radius > 0, got {radius!r}")
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)) or n_points < 4:
        raise InvalidInputError(f"n_points: expected an int >= 4, got {n_points!r}")
    k = np.arange(n_points) + 0.5
    z = 1.0 - 2.0 * k / n_points
    phi = np.pi * (1.0 + 5.0**0.5) * k
    rho = np.sqrt(1.0 - z * z)
    surf = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    return np.vstack([c, c + r * surf])


class TetMaterialPoints:
    """Material points of a tetrahedral body: location, interpolation of the nodal
    displacement, deformation gradients and consistent point forces (what
    :class:`~riskplan.deformable.TetTissue` offers at material points; it provides
    ``mesh`` (:class:`~riskplan.deformable.TetMesh`), the current displacement ``_u (3N,)``
    and the shape gradients ``_G (T, 4, 3)``).
    """

    def locate(self, points):
        """Containing elements and barycentric weights of reference points (no error outside).

        Parameters
        ----------
        points : array_like, shape (P, 3)
            Reference (material) positions.

        Returns
        -------
        elements : ndarray, shape (P,)
            Containing element, ``-1`` for a point outside the tissue.
        weights : ndarray, shape (P, 4)
            Barycentric weights ``λ_a`` (rows sum to 1).
        """
        pts = np.ascontiguousarray(as_array(points, "points", last_dim=3).reshape(-1, 3))
        return find_points(self.mesh, pts)

    def contains(self, points) -> np.ndarray:
        """Which reference points lie in the tissue.

        Parameters
        ----------
        points : array_like, shape (P, 3)
            Reference positions.

        Returns
        -------
        ndarray of bool, shape (P,)
        """
        return self.locate(points)[0] >= 0

    def interpolator(self, points, name: str = "points") -> Interpolator:
        """Barycentric interpolation at material points (an embedded target or obstacle:
        :func:`sphere_points`), located once.

        Parameters
        ----------
        points : array_like, shape (P, 3) or (3,)
            Reference positions.
        name : str
            What the points are ("target", "obstacle 2"); named in the error.

        Returns
        -------
        Interpolator
            ``.interpolate(u)``, ``.positions(u)``, ``.spread(F)`` on ``(N, 3)`` nodal arrays.

        Raises
        ------
        InvalidInputError
            Some point lies outside the tissue (the error names the set and the points).
        """
        return locate3d(self.mesh, points, name)

    def displacement_at(self, points, u=None) -> np.ndarray:
        """Displacement of material points, ``u(X) = Σ_a λ_a(X) u_a`` (P1 interpolant).

        Parameters
        ----------
        points : array_like, shape (P, 3)
            Reference positions inside the tissue.
        u : array_like, shape (N, 3), optional
            Nodal displacement; ``None``: the current state.

        Returns
        -------
        ndarray, shape (P, 3)
        """
        return self.interpolator(points).interpolate(self._field(u))

    def positions(self, points, u=None) -> np.ndarray:
        """Deformed positions ``X + u(X)`` of material points.

        Parameters
        ----------
        points : array_like, shape (P, 3)
            Reference positions inside the tissue.
        u : array_like, shape (N, 3), optional
            Nodal displacement; ``None``: the current state.

        Returns
        -------
        ndarray, shape (P, 3)
        """
        return self.interpolator(points).positions(self._field(u))

    def deformation_gradient_at(self, points, u=None) -> np.ndarray:
        """Deformation gradient ``F = I + ∇_X u`` at material points (constant in each
        element; a point on a shared face takes one of its elements).

        Parameters
        ----------
        points : array_like, shape (P, 3)
            Reference positions inside the tissue.
        u : array_like, shape (N, 3), optional
            Nodal displacement; ``None``: the current state.

        Returns
        -------
        ndarray, shape (P, 3, 3)
        """
        ip = self.interpolator(points)
        u3 = self._field(u)
        e = ip.elements
        return deformation_gradients(u3[self.mesh.tets[e]], self._G[e])

    def point_forces(self, points, forces) -> np.ndarray:
        """Consistent nodal forces of point forces at material points:
        ``f_a = λ_a(X_p) F_p`` over the containing element's four nodes.

        Parameters
        ----------
        points : array_like, shape (P, 3)
            Reference positions inside the tissue.
        forces : array_like, shape (P, 3)
            Force at each point.

        Returns
        -------
        ndarray, shape (N, 3)
            Nodal forces (their sum is the resultant of ``forces``).
        """
        ip = self.interpolator(points)
        f = as_array(forces, "forces", shape=(ip.n_points, 3))
        return ip.spread(f)

    def _field(self, u) -> np.ndarray:
        if u is None:
            return self._u.reshape(-1, 3)
        return as_array(u, "u", shape=(self.mesh.n_nodes, 3))
