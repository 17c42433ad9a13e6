"""P1 triangle geometry and kinematics: pure array functions of ``nodes (N, 2)``,
``triangles (T, 3)`` and element displacements (paper V: the 2-D FEM bodies of both
scenarios are P1 triangle meshes).

:class:`~riskplan.deformable.mesh.TissueMesh` caches what depends only on the reference
mesh (``shape_gradients``, ``barycentric_maps``) as its own cached properties; the
functions here compute them and the per-iterate quantities (``F``, ``det F``, ``F⁻¹``).
"""

from __future__ import annotations

import numpy as np

# the barycentric maps of P1 elements are plain triangle geometry, shared with point location
from riskplan.geometry2d import barycentric_maps as barycentric_maps


def signed_areas(nodes: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Signed areas ``(T,)`` of triangles ``(T, 3)`` over ``nodes (N, 2)``; > 0 when
    counter-clockwise: ``A = ½ [(x₁−x₀)(y₂−y₀) − (x₂−x₀)(y₁−y₀)]``."""
    p = nodes[triangles]
    d1 = p[:, 1] - p[:, 0]
    d2 = p[:, 2] - p[:, 0]
    return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def boundary_edges(triangles: np.ndarray) -> np.ndarray:
    """Edges ``(E, 2)`` used by exactly one triangle, oriented as in that triangle
    (so counter-clockwise around the body when the triangles are)."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = np.sort(e, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return np.ascontiguousarray(e[counts[inv.ravel()] == 1])


def shape_gradients(nodes: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``(T, 3, 2)`` reference gradients ``∇_X N_a`` of the P1 shape functions:
    ``∇N1 = (y2 − y0, x0 − x2)/2A``, ``∇N2 = (y0 − y1, x1 − x0)/2A``, ``∇N0 = −(∇N1 + ∇N2)``."""
    p = nodes[triangles]
    d1 = p[:, 1] - p[:, 0]
    d2 = p[:, 2] - p[:, 0]
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]  # 2 A
    g1 = np.stack([d2[:, 1], -d2[:, 0]], axis=1) / det[:, None]
    g2 = np.stack([-d1[:, 1], d1[:, 0]], axis=1) / det[:, None]
    return np.stack([-(g1 + g2), g1, g2], axis=1)


def deformation_gradients(u_elem: np.ndarray, G: np.ndarray) -> np.ndarray:
    """``F = I + Σ_a u_a ⊗ ∇N_a`` ``(T, 2, 2)`` from element displacements ``(T, 3, 2)``
    and shape gradients ``G (T, 3, 2)``."""
    F = np.einsum("tai,taj->tij", u_elem, G)
    F[:, 0, 0] += 1.0
    F[:, 1, 1] += 1.0
    return F


def determinants_and_inverses(F: np.ndarray):
    """``(J (T,), F⁻¹ (T, 2, 2))`` of 2×2 matrices ``F (T, 2, 2)`` (closed form; no
    check for ``J = 0``)."""
    J = F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]
    Finv = np.empty_like(F)
    Finv[:, 0, 0] = F[:, 1, 1]
    Finv[:, 1, 1] = F[:, 0, 0]
    Finv[:, 0, 1] = -F[:, 0, 1]
    Finv[:, 1, 0] = -F[:, 1, 0]
    Finv /= J[:, None, None]
    return J, Finv
