"""Consistent nodal forces for P1 triangle meshes (dead loads, reference configuration).

* point loads: ``f_{n_a} = N_a(X_p) F`` — the P1 shape functions (barycentric weights)
  at the load point (paper V-A: the needle pushes the tissue at its tip);
* patch loads: a force ``F`` spread with a smooth bump ``w(r) = (1 − r²/R²)²`` (r < R)
  over the boundary arc (``on="boundary"``) or the area (``on="area"``) within radius
  ``R`` of a centre, ``f_a = F ∫ N_a w / ∫ w`` — so the total force is exactly ``F``
  (paper V-B: manipulators push on the boundary; spreading keeps elements from
  inverting under large forces);
* body forces ``f_a = ∫ N_a b dx`` and boundary tractions ``f_a = ∫_∂Ω N_a t ds``
  (used by the patch and convergence tests, and available to users).

Every function returns nodal forces ``(N, 2)``; the ``*_weights`` variants return the
``(N,)`` weights of a unit force so a hot loop rebuilds loads with one outer product.
"""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array
from riskplan.deformable.material_points import locate
from riskplan.deformable.mesh import TissueMesh
from riskplan.errors import InvalidInputError

# 3-point Gauss-Legendre on [0, 1]
_GL_X = 0.5 + 0.5 * np.array([-np.sqrt(3.0 / 5.0), 0.0, np.sqrt(3.0 / 5.0)])
_GL_W = np.array([5.0, 8.0, 5.0]) / 18.0

# degree-4 symmetric 6-point rule on the reference triangle (Dunavant), barycentric
_D4_A, _D4_B = 0.445948490915965, 0.091576213509771
_D4_WA, _D4_WB = 0.223381589678011, 0.109951743655322
_TRI_BARY = np.array(
    [
        [_D4_A, _D4_A, 1 - 2 * _D4_A],
        [_D4_A, 1 - 2 * _D4_A, _D4_A],
        [1 - 2 * _D4_A, _D4_A, _D4_A],
        [_D4_B, _D4_B, 1 - 2 * _D4_B],
        [_D4_B, 1 - 2 * _D4_B, _D4_B],
        [1 - 2 * _D4_B, _D4_B, _D4_B],
    ]
)
_TRI_W = np.array([_D4_WA] * 3 + [_D4_WB] * 3)  # sums to 1 (times the triangle area)


def _check_mesh(mesh) -> None:
    if not isinstance(mesh, TissueMesh):
        raise InvalidInputError(f"mesh: expected a TissueMesh, got {type(mesh).__name__}")


def subdivided_triangle_rule(k: int):
    """Barycentric points ``(Q, 3)`` and weights ``(Q,)`` (sum 1) of the degree-4 rule
    applied on a uniform ``k × k`` subdivision of the triangle."""
    if k == 1:
        return _TRI_BARY, _TRI_W
    sub = []
    for i in range(k):
        for j in range(k - i):
            a = np.array([i, j, k - i - j], dtype=float) / k
            b = np.array([i + 1, j, k - i - j - 1], dtype=float) / k
            c = np.array([i, j + 1, k - i - j - 1], dtype=float) / k
            sub.append((a, b, c))
            if i + j < k - 1:
                d = np.array([i + 1, j + 1, k - i - j - 2], dtype=float) / k
                sub.append((b, d, c))
    pts = [_TRI_BARY @ np.stack(s) for s in sub]
    return np.concatenate(pts), np.tile(_TRI_W, len(sub)) / len(sub)


def _scatter(n_nodes: int, idx: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """Sum ``vals (..., d)`` into ``(n_nodes, d)`` at ``idx (...)``."""
    d = vals.shape[-1]
    out = np.empty((n_nodes, d))
    flat = idx.ravel()
    for k in range(d):
        out[:, k] = np.bincount(flat, vals[..., k].ravel(), minlength=n_nodes)
    return out


def point_load(mesh: TissueMesh, points, forces) -> np.ndarray:
    """Consistent nodal forces of point forces at reference points (P1 shape functions there).

    Points outside the body raise :class:`InvalidInputError`. For repeated loads at the same
    points use :func:`riskplan.deformable.locate` once and ``Interpolator.spread``.

    Parameters
    ----------
    mesh : TissueMesh
        The triangle mesh.
    points : array_like, (P, 2)
        Reference positions.
    forces : array_like, (P, 2)
        Forces.

    Returns
    -------
    numpy.ndarray, (N, 2)
    """
    pts = as_array(points, "points", last_dim=2).reshape(-1, 2)
    f = as_array(forces, "forces", last_dim=2).reshape(-1, 2)
    if len(f) != len(pts):
        raise InvalidInputError(f"forces: expected {len(pts)} rows (one per point), got {len(f)}")
    return locate(mesh, pts).spread(f)


def body_load(mesh: TissueMesh, body_force, *, refine: int = 1) -> np.ndarray:
    r"""Consistent nodal forces of a body force.

    .. math:: f_a = \int N_a\, b \,\mathrm{d}x

    Degree-4 quadrature on each element.

    Parameters
    ----------
    mesh : TissueMesh
        The triangle mesh.
    body_force : array_like, (2,), or callable
        A constant, or ``b(x (Q, 2)) -> (Q, 2)``; force per unit area.
    refine : int
        Subdivide each element ``refine × refine`` times for rough integrands.

    Returns
    -------
    numpy.ndarray, (N, 2)
    """
    _check_mesh(mesh)
    bary, w = subdivided_triangle_rule(int(refine))
    p = mesh.nodes[mesh.triangles]  # (T, 3, 2)
    x = np.einsum("qa,tad->tqd", bary, p)  # (T, Q, 2)
    if callable(body_force):
        b = as_array(
            body_force(x.reshape(-1, 2)), "body_force(x)", shape=(x.shape[0] * x.shape[1], 2)
        )
        b = b.reshape(x.shape)
    else:
        b = np.broadcast_to(as_array(body_force, "body_force", shape=(2,)), x.shape)
    # (T, 3, 2): Σ_q area w_q N_a(x_q) b(x_q)
    fe = np.einsum("t,q,qa,tqd->tad", mesh.areas, w, bary, b)
    return _scatter(mesh.n_nodes, mesh.triangles, fe)


def traction_load(mesh: TissueMesh, traction, *, edges=None) -> np.ndarray:
    r"""Consistent nodal forces of a boundary traction.

    .. math:: f_a = \int N_a\, t \,\mathrm{d}s

    3-point Gauss-Legendre per edge (exact for tractions up to degree 4 in arc length).

    Parameters
    ----------
    mesh : TissueMesh
        The triangle mesh.
    traction : array_like, (2,), or callable
        A constant, or ``t(x (Q, 2), n (Q, 2)) -> (Q, 2)`` of position and outward unit normal
        (e.g. ``σ n`` for a stress field ``σ``).
    edges : array_like of int, (E, 2), optional
        Restrict the load to these boundary edges (default: all of them).

    Returns
    -------
    numpy.ndarray, (N, 2)
    """
    _check_mesh(mesh)
    e = mesh.boundary_edges if edges is None else np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    a, b = mesh.nodes[e[:, 0]], mesh.nodes[e[:, 1]]
    t = b - a
    length = np.linalg.norm(t, axis=1)
    normal = np.stack([t[:, 1], -t[:, 0]], axis=1) / length[:, None]  # outward for CCW boundary
    x = a[:, None, :] + _GL_X[None, :, None] * t[:, None, :]  # (E, 3, 2)
    if callable(traction):
        tr = traction(x.reshape(-1, 2), np.repeat(normal, 3, axis=0))
        tr = as_array(tr, "traction(x, n)", shape=(x.shape[0] * 3, 2)).reshape(x.shape)
    else:
        tr = np.broadcast_to(as_array(traction, "traction", shape=(2,)), x.shape)
    N = np.stack([1.0 - _GL_X, _GL_X], axis=1)  # (3, 2) shape functions of the edge ends
    fe = np.einsum("e,q,qa,eqd->ead", length, _GL_W, N, tr)  # (E, 2, 2)
    return _scatter(mesh.n_nodes, e, fe)


def _bump(r2: np.ndarray, radius: float) -> np.ndarray:
    s = 1.0 - r2 / radius**2
    return np.where(s > 0.0, s * s, 0.0)


def patch_weights(mesh: TissueMesh, center, radius: float, *, on: str = "boundary") -> np.ndarray:
    r"""Nodal weights of a unit force spread over a patch.

    .. math:: w_a = \frac{\int N_a \varphi}{\int \varphi}, \qquad
       \varphi(x) = \bigl(1 - |x - c|^2 / R^2\bigr)^2 \ \text{for}\ |x - c| < R

    integrated over the boundary curve (``on="boundary"``) or over the body (``on="area"``),
    with edges / elements subdivided so the bump is resolved (at least 4 sub-intervals per
    radius). Raises :class:`InvalidInputError` when the patch contains no boundary (or no body).

    Parameters
    ----------
    mesh : TissueMesh
        The triangle mesh.
    center : array_like, (2,)
        Patch centre ``c`` (reference frame).
    radius : float
        Patch radius ``R``.
    on : str
        ``"boundary"`` or ``"area"``.

    Returns
    -------
    numpy.ndarray, (N,)
        Weights summing to 1.
    """
    _check_mesh(mesh)
    c = as_array(center, "center", shape=(2,))
    radius = float(radius)
    if not np.isfinite(radius) or radius <= 0.0:
        raise InvalidInputError(f"radius: expected a finite radius > 0, got {radius}")
    if on == "boundary":
        e = mesh.boundary_edges
        a, b = mesh.nodes[e[:, 0]], mesh.nodes[e[:, 1]]
        t = b - a
        L2 = (t**2).sum(1)
        s = np.clip(((c - a) * t).sum(1) / L2, 0.0, 1.0)
        near = ((a + s[:, None] * t - c) ** 2).sum(1) < radius**2
        if not np.any(near):
            raise InvalidInputError(f"center: no boundary within radius {radius:g} of {c.tolist()}")
        e, a, t = e[near], a[near], t[near]
        length = np.sqrt(L2[near])
        m = int(np.ceil(4.0 * length.max() / radius))
        # m sub-intervals per edge, 3 Gauss points each
        u = ((np.arange(m)[:, None] + _GL_X[None, :]) / m).ravel()  # (Q,)
        wq = np.tile(_GL_W, m) / m
        x = a[:, None, :] + u[None, :, None] * t[:, None, :]  # (E, Q, 2)
        phi = _bump(((x - c) ** 2).sum(-1), radius) * length[:, None] * wq[None, :]
        N = np.stack([1.0 - u, u], axis=1)  # (Q, 2)
        fe = np.einsum("eq,qa->ea", phi, N)
        idx = e
    elif on == "area":
        p = mesh.nodes[mesh.triangles]
        cen = p.mean(axis=1)
        ext = np.sqrt(((p - cen[:, None]) ** 2).sum(-1)).max(1)
        near = np.sqrt(((cen - c) ** 2).sum(1)) < radius + ext
        if not np.any(near):
            raise InvalidInputError(
                f"center: the patch of radius {radius:g} at {c.tolist()} misses the body"
            )
        k = max(1, int(np.ceil(4.0 * ext[near].max() / radius)))
        bary, wq = subdivided_triangle_rule(k)
        x = np.einsum("qa,tad->tqd", bary, p[near])
        phi = _bump(((x - c) ** 2).sum(-1), radius) * mesh.areas[near][:, None] * wq[None, :]
        fe = np.einsum("tq,qa->ta", phi, bary)
        idx = mesh.triangles[near]
    else:
        raise InvalidInputError(f"on: expected 'boundary' or 'area', got {on!r}")
    total = fe.sum()
    if not total > 0.0:
        raise InvalidInputError(
            f"center: the patch of radius {radius:g} at {c.tolist()} has no {on}"
        )
    return np.bincount(idx.ravel(), fe.ravel() / total, minlength=mesh.n_nodes)


def patch_load(
    mesh: TissueMesh, center, radius: float, force, *, on: str = "boundary"
) -> np.ndarray:
    """Nodal forces of a total force spread over a patch (:func:`patch_weights`).

    Parameters
    ----------
    mesh : TissueMesh
        The triangle mesh.
    center : array_like, (2,)
        Patch centre.
    radius : float
        Patch radius.
    force : array_like, (2,)
        Total force.
    on : str
        ``"boundary"`` or ``"area"``.

    Returns
    -------
    numpy.ndarray, (N, 2)
        Summing to ``force``.
    """
    f = as_array(force, "force", shape=(2,))
    return np.outer(patch_weights(mesh, center, radius, on=on), f)
