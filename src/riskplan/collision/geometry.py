"""Pure array helpers for obstacle geometry: whitening, closed-mesh and closed-polyline
checks, extrusion, and the checks of query points.

Polygon checks and every other planar query live in :mod:`riskplan.geometry2d`.

Whitening (MDN paper eq. 8): for a Gaussian ``N(mu, Sigma)`` with ``Sigma^{-1} = U^T U``,
``y = U (x - mu)`` maps the Gaussian to ``N(0, I)`` and the Mahalanobis distance
``sqrt((x - mu)^T Sigma^{-1} (x - mu))`` to the Euclidean norm ``|y|``. It is linear, so
triangles stay triangles and segments stay segments.
"""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array
from riskplan.errors import InvalidInputError


def whiten(points, mean, precision_cholesky) -> np.ndarray:
    """The whitening map of eq. 8 (MDN paper), ``y = U (x - mu)``.

    Parameters
    ----------
    points : array_like, (..., N, d)
        Points ``x``.
    mean : array_like, (..., d)
        Means ``mu``; leading axes broadcast.
    precision_cholesky : array_like, (..., d, d)
        Upper triangular ``U`` with ``Sigma^{-1} = U^T U``.

    Returns
    -------
    numpy.ndarray, (..., N, d)
        Whitened points ``y`` (standard-normal units).
    """
    x = np.asarray(points, dtype=np.float64)
    mu = np.asarray(mean, dtype=np.float64)
    u = np.asarray(precision_cholesky, dtype=np.float64)
    return np.einsum("...ij,...nj->...ni", u, x - mu[..., None, :])


def unwhiten(points, mean, precision_cholesky) -> np.ndarray:
    """Inverse of :func:`whiten`: ``x = mu + U^{-1} y``.

    Parameters
    ----------
    points : array_like, (..., N, d)
        Whitened points ``y``.
    mean : array_like, (..., d)
        Means ``mu``.
    precision_cholesky : array_like, (..., d, d)
        Upper triangular ``U``.

    Returns
    -------
    numpy.ndarray, (..., N, d)
        Points ``x`` in the original frame.
    """
    y = np.asarray(points, dtype=np.float64)
    u = np.asarray(precision_cholesky, dtype=np.float64)
    sol = np.linalg.solve(u[..., None, :, :], y[..., :, :, None])[..., 0]
    return np.asarray(mean, dtype=np.float64)[..., None, :] + sol


def mahalanobis(points, mean, precision_cholesky) -> np.ndarray:
    """Mahalanobis distance ``sqrt((x - mu)^T U^T U (x - mu)) = ||U (x - mu)||``.

    Parameters
    ----------
    points : array_like, (..., N, d)
        Points ``x``.
    mean : array_like, (..., d)
        Means ``mu``.
    precision_cholesky : array_like, (..., d, d)
        Upper triangular ``U``.

    Returns
    -------
    numpy.ndarray, (..., N)
        Distances in standard deviations.
    """
    return np.linalg.norm(whiten(points, mean, precision_cholesky), axis=-1)


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Areas ``(F,)`` of triangles ``faces (F, 3)`` over ``vertices (V, 3)``."""
    t = vertices[faces]
    return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume enclosed by closed triangles (positive for outward orientation)."""
    t = vertices[faces]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)


def check_closed_mesh(vertices: np.ndarray, faces: np.ndarray, name: str) -> None:
    """Raise :class:`InvalidInputError` unless the triangles form closed, edge-manifold,
    consistently oriented surfaces without degenerate faces.

    Every directed edge ``(a, b)`` must occur exactly once and its reverse ``(b, a)`` exactly
    once: an edge used by more than two faces is non-manifold, an edge used once is a hole,
    an edge used twice in the same direction means inconsistent orientation.
    """
    if len(faces) == 0:
        raise InvalidInputError(f"{name}: mesh has no faces")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InvalidInputError(f"{name}: face indices out of range [0, {len(vertices)})")
    if np.any(
        (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    ):
        raise InvalidInputError(f"{name}: degenerate face (repeated vertex index)")
    scale = float(np.ptp(vertices, axis=0).max()) or 1.0
    area = triangle_areas(vertices, faces)
    bad = np.flatnonzero(area <= 1e-12 * scale * scale)
    if bad.size:
        raise InvalidInputError(
            f"{name}: {bad.size} degenerate (zero-area) triangles, first is face {int(bad[0])}"
        )
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    nv = len(vertices)
    key = e[:, 0].astype(np.int64) * nv + e[:, 1]
    uniq, counts = np.unique(key, return_counts=True)
    if np.any(counts > 1):
        k = uniq[counts > 1][0]
        raise InvalidInputError(
            f"{name}: non-manifold or inconsistently oriented mesh (directed edge {int(k // nv)}->{int(k % nv)} "
            f"is used by {int(counts[counts > 1][0])} faces)"
        )
    rev = e[:, 1].astype(np.int64) * nv + e[:, 0]
    has_rev = np.isin(rev, uniq)
    if not np.all(has_rev):
        i = int(np.flatnonzero(~has_rev)[0])
        raise InvalidInputError(
            f"{name}: mesh is not closed (watertight): edge {int(e[i, 0])}-{int(e[i, 1])} has only one face "
            f"({int((~has_rev).sum())} open edges)"
        )


def extrude_polygon(poly: np.ndarray, z0: float, z1: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed, outward-oriented triangle mesh of the prism ``poly x [z0, z1]`` (``poly`` CCW).

    Caps are fan-triangulated through their centroid, so the polygon must be star-shaped
    w.r.t. its vertex centroid (true for convex polygons); used for 2-D/3-D consistency checks.
    """
    k = len(poly)
    c = poly.mean(axis=0)
    bottom = np.column_stack([poly, np.full(k, z0)])
    top = np.column_stack([poly, np.full(k, z1)])
    V = np.vstack([bottom, top, [[c[0], c[1], z0], [c[0], c[1], z1]]])
    cb, ct = 2 * k, 2 * k + 1
    faces = []
    for i in range(k):
        j = (i + 1) % k
        faces += [[i, j, k + j], [i, k + j, k + i], [cb, j, i], [ct, k + i, k + j]]
    return V, np.asarray(faces, dtype=np.int64)


# a mesh larger than this many robot lengths is taken to be in millimetres, not metres: the
# largest anatomy a continuum robot works in (a chest, ~0.4 m) is a few robot lengths, while a
# millimetre-valued mesh of the same anatomy is ~1000 times larger
MILLIMETRE_FACTOR = 50.0


def check_metre_scale(
    vertices,
    robot_length: float,
    *,
    source: str = "mesh",
    remedy: str = "Scale them by 0.001 before use",
) -> float:
    """Raise :class:`InvalidInputError` when a mesh's extent suggests millimetres where metres
    are expected: its bounding-box diagonal exceeds ``MILLIMETRE_FACTOR`` robot lengths.

    Parameters
    ----------
    vertices : (V, 3) array
        The mesh's vertices (m expected).
    robot_length : float
        The robot's backbone length (m) the extent is judged against.
    source : str
        The file, option or field named in the error.
    remedy : str
        The sentence that ends the error (what the user can do).

    Returns
    -------
    float
        The bounding-box diagonal (m).
    """
    V = np.asarray(vertices, dtype=np.float64)
    diag = float(np.linalg.norm(np.ptp(V, axis=0)))
    if diag > MILLIMETRE_FACTOR * robot_length:
        raise InvalidInputError(
            f"{source}: the mesh spans {diag:.4g} m, {diag / robot_length:.0f} times the robot's length "
            f"({robot_length:.4g} m); its coordinates look like millimetres where metres are expected. "
            f"{remedy}"
        )
    return diag


def check_finite_vertices(V: np.ndarray, name: str) -> None:
    """Name the first vertex with a NaN or infinite coordinate."""
    bad = ~np.isfinite(V).all(axis=-1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InvalidInputError(
            f"{name}: vertex {i} is not finite (NaN or inf: {V[i].tolist()}); {int(bad.sum())} such vertices"
        )


def as_points(points, d: int, name: str = "points") -> tuple[np.ndarray, tuple]:
    """``points (..., d)`` checked (finite) as a C-contiguous ``(N, d)`` array, and the
    leading shape ``(...)``."""
    arr = as_array(points, name, finite=False)
    if arr.ndim == 0 or arr.shape[-1] != d:
        raise InvalidInputError(
            f"{name}: expected shape (..., {d}) for a {d}-D environment, got {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{name}: contains NaN or inf")
    return np.ascontiguousarray(arr.reshape(-1, d)), arr.shape[:-1]


def as_point(p, name: str, d: int) -> np.ndarray:
    """One finite point ``(d,)``."""
    arr = as_array(p, name, finite=False)
    if arr.shape != (d,):
        raise InvalidInputError(f"{name}: expected shape ({d},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{name}: contains NaN or inf")
    return arr


def check_closed_polyline(V: np.ndarray, F: np.ndarray, name: str) -> None:
    """Directed edges ``F (E, 2)`` into ``V (n, 2)`` form closed, simple, consistently oriented
    loops without degenerate or zero-length edges (the 2-D twin of :func:`check_closed_mesh`)."""
    if len(F) < 3:
        raise InvalidInputError(f"{name}: a polygon needs at least 3 edges, got {len(F)}")
    if F.min() < 0 or F.max() >= len(V):
        raise InvalidInputError(f"{name}: edge indices out of range [0, {len(V)})")
    if np.any(F[:, 0] == F[:, 1]):
        raise InvalidInputError(f"{name}: degenerate edge (repeated vertex index)")
    out = np.bincount(F[:, 0], minlength=len(V))
    inn = np.bincount(F[:, 1], minlength=len(V))
    used = (out + inn) > 0
    if np.any(out[used] != 1) or np.any(inn[used] != 1):
        raise InvalidInputError(
            f"{name}: edges do not form closed, simple, consistently oriented loops"
        )
    lengths = np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1)
    if np.any(lengths <= 1e-12 * (float(np.ptp(V[used], axis=0).max()) or 1.0)):
        raise InvalidInputError(f"{name}: zero-length edge")


def polygon_order(F: np.ndarray) -> np.ndarray:
    """Vertex order of one closed loop of directed edges."""
    nxt = dict(zip(F[:, 0].tolist(), F[:, 1].tolist()))
    start = int(F[0, 0])
    order = [start]
    v = nxt[start]
    while v != start:
        order.append(v)
        v = nxt[v]
    return np.asarray(order)
