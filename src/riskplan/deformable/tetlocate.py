"""Material points of a tetrahedral mesh: point location (k-d tree on element centroids,
then an exhaustive search), barycentric interpolators, and spherical material-point sets
(embedded obstacles and targets) for :mod:`riskplan.deformable.tissue3d`.
"""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array
from riskplan.deformable.material_points import Interpolator
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
