"""Material points in a P1 mesh: point location and precomputed barycentric weights.

Obstacles, the goal region, target points and load points are *material* points: they
are fixed in the reference configuration and move with the tissue (paper V-A: "obstacles
and goal region are embedded in the tissue"). Their displacement is the P1 interpolant

    u(X_p) = Σ_{a=1..3} λ_a(X_p) u_{n_a}          (barycentric weights λ_a of X_p),

and the consistent nodal forces of a point force ``F`` at ``X_p`` are the transpose,
``f_{n_a} = λ_a(X_p) F`` (P1 shape functions at the point). An :class:`Interpolator`
holds ``(n_a, λ_a)`` for a set of points so hot loops need only gathers and sums.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_array
from riskplan.deformable.mesh import TissueMesh
from riskplan.errors import InvalidInputError
from riskplan.geometry2d import BARYCENTRIC_TOL

#: A point counts as inside when its smallest barycentric coordinate is >= -INSIDE_TOL
#: (the closed convention of :mod:`riskplan.geometry2d`).
INSIDE_TOL = BARYCENTRIC_TOL


def locate_points(maps: np.ndarray, points: np.ndarray, chunk: int = 256, candidates=None):
    """Containing element ``(P,)`` and barycentric weights ``(P, 3)`` of ``points (P, 2)``
    given the elements' ``maps (T, 3, 3)`` (``TissueMesh.barycentric_maps``), by exhaustive
    search: the reference for the grid locator ``TissueMesh.locator``, which :func:`locate`
    and :func:`contains` use.

    Picks, for each point, the element whose smallest barycentric coordinate is largest;
    element ``-1`` when that value is below ``-INSIDE_TOL`` (outside the mesh).
    ``candidates (P, k)``: optional element indices to try first (e.g. the elements with
    the nearest centroids); points not found among them are searched exhaustively, so
    the result does not depend on the candidates.
    """
    P = len(points)
    elem = np.full(P, -1, dtype=np.int64)
    lam = np.empty((P, 3))
    todo = np.arange(P)
    if candidates is not None and P:
        b = (
            np.einsum("pkij,pj->pki", maps[candidates][:, :, :, :2], points)
            + maps[candidates][:, :, :, 2]
        )
        worst = b.min(axis=2)  # (P, k)
        j = worst.argmax(axis=1)
        rows = np.arange(P)
        ok = worst[rows, j] >= -INSIDE_TOL
        elem[ok] = candidates[rows[ok], j[ok]]
        lam[ok] = b[rows[ok], j[ok]]
        todo = np.flatnonzero(~ok)
    for s in range(0, len(todo), chunk):
        idx = todo[s : s + chunk]
        q = points[idx]
        # (T, 3, 2) @ (2, p) + (T, 3, 1) -> (p, T, 3)
        b = np.einsum("tij,pj->pti", maps[:, :, :2], q) + maps[None, :, :, 2]
        worst = b.min(axis=2)  # (p, T)
        e = worst.argmax(axis=1)
        ok = worst[np.arange(len(q)), e] >= -INSIDE_TOL
        elem[idx] = np.where(ok, e, -1)
        lam[idx] = b[np.arange(len(q)), e]
    return elem, lam


@dataclass(frozen=True, eq=False)
class Interpolator:
    """Barycentric interpolation at ``P`` material points of a mesh with ``N`` nodes.

    Attributes: ``points (P, d)`` reference positions, ``elements (P,)`` containing
    elements, ``node_index (P, k)`` their nodes, ``weights (P, k)`` barycentric weights
    (rows sum to 1), ``n_nodes``; ``d = 2, k = 3`` for triangles, ``d = 3, k = 4`` for
    tetrahedra (:func:`riskplan.deformable.tetlocate.locate3d`).
    """

    points: np.ndarray
    elements: np.ndarray
    node_index: np.ndarray
    weights: np.ndarray
    n_nodes: int

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    def interpolate(self, u: np.ndarray) -> np.ndarray:
        """A nodal field at the located points; exact for fields linear in each element (hot path).

        Parameters
        ----------
        u : numpy.ndarray, (..., N, d)
            Nodal values.

        Returns
        -------
        numpy.ndarray, (..., P, d)
            ``Σ_a λ_a u_{n_a}`` with the points' barycentric weights ``λ``.
        """
        return np.einsum("...pad,pa->...pd", u[..., self.node_index, :], self.weights)

    def positions(self, u: np.ndarray) -> np.ndarray:
        """Deformed positions ``X_p + u(X_p)`` of the located points.

        Parameters
        ----------
        u : numpy.ndarray, (..., N, 2)
            Nodal displacements.

        Returns
        -------
        numpy.ndarray, (..., P, 2)
        """
        return self.points + self.interpolate(u)

    def spread(self, forces: np.ndarray) -> np.ndarray:
        """Consistent nodal forces of point forces (transpose of :meth:`interpolate`: ``f_{n_a} += λ_a F_p``).

        Parameters
        ----------
        forces : numpy.ndarray, (P, d)
            Forces at the located points.

        Returns
        -------
        numpy.ndarray, (N, d)
        """
        forces = np.asarray(forces, dtype=np.float64)
        d = forces.shape[-1]
        out = np.zeros((self.n_nodes, d))
        contrib = self.weights[:, :, None] * forces[:, None, :]  # (P, 3, d)
        for k in range(d):
            out[:, k] = np.bincount(
                self.node_index.ravel(), contrib[:, :, k].ravel(), minlength=self.n_nodes
            )
        return out

    def matrix(self):
        """``scipy.sparse.csr_matrix (P, N)`` with ``matrix @ u[:, k] = interpolate(u)[:, k]``.

        Returns
        -------
        scipy.sparse.csr_matrix
            ``(P, N)``.
        """
        from scipy import sparse

        rows = np.repeat(np.arange(self.n_points), self.weights.shape[1])
        return sparse.csr_matrix(
            (self.weights.ravel(), (rows, self.node_index.ravel())),
            shape=(self.n_points, self.n_nodes),
        )


def locate(mesh: TissueMesh, points) -> Interpolator:
    """Locate material points in ``mesh`` and precompute their barycentric weights.

    Raises :class:`InvalidInputError` naming the points that lie outside the mesh
    (a point on the boundary, within ``INSIDE_TOL`` in barycentric terms, is inside).

    Parameters
    ----------
    mesh : TissueMesh
        The triangle mesh (reference configuration).
    points : array_like, (P, 2) or (2,)
        Reference positions.

    Returns
    -------
    Interpolator
    """
    if not isinstance(mesh, TissueMesh):
        raise InvalidInputError(f"mesh: expected a TissueMesh, got {type(mesh).__name__}")
    pts = as_array(points, "points", last_dim=2)
    if pts.ndim > 2:
        raise InvalidInputError(f"points: expected shape (P, 2) or (2,), got {pts.shape}")
    pts = np.ascontiguousarray(pts.reshape(-1, 2))
    elem, lam = mesh.locator.locate_points(pts)
    outside = np.flatnonzero(elem < 0)
    if outside.size:
        raise InvalidInputError(
            f"points: {outside.size} point(s) lie outside the body, e.g. index {outside[:5].tolist()} "
            f"at {pts[outside[:3]].tolist()}"
        )
    for a in (pts, elem, lam):
        a.setflags(write=False)
    idx = mesh.triangles[elem]
    idx.setflags(write=False)
    return Interpolator(
        points=pts, elements=elem, node_index=idx, weights=lam, n_nodes=mesh.n_nodes
    )


def contains(mesh: TissueMesh, points) -> np.ndarray:
    """Which reference points lie in the mesh (no error for those outside).

    Parameters
    ----------
    mesh : TissueMesh
        The triangle mesh.
    points : array_like, (P, 2)
        Reference positions.

    Returns
    -------
    numpy.ndarray of bool, (P,)
    """
    pts = np.ascontiguousarray(as_array(points, "points", last_dim=2).reshape(-1, 2))
    elem, _ = mesh.locator.locate_points(pts)
    return elem >= 0
