"""Voxel obstacles as an exact boundary surface, for the collision bound and Monte Carlo.

A voxel obstacle (the Kuntz lab's ``VoxelOctree``, a segmentation's occupied cells) is the
union of its occupied axis-aligned cells. Its boundary is made of the cell faces that
separate an occupied cell from an empty one; each such face is a convex planar piece (a
square), split here into two triangles with the outward normal (from the occupied cell to
the empty one). :func:`voxel_environment` returns that surface as an
:class:`~riskplan.collision.environment.Environment`, so every estimator of the package runs
on it unchanged:

* the eq.-9 bound (Patil et al., :mod:`riskplan.collision.gaussian`) takes the faces as the
  convex pieces of the obstacle surface; for a Gaussian ``N(μ, Σ)`` and one axis-aligned face
  the whitened distance is the closed form of the nearest point of the whitened square;
* point membership is the winding number of the closed surface: 1 inside the union of the
  cells, 0 outside, with no approximation (no marching-cubes chamfer at corners, no
  decimation).

Cells that touch along an edge only (diagonal neighbours) make that edge non-manifold (four
faces meet there); the surface is still closed and consistently oriented, and the winding
number and the face-wise bound do not need manifold edges, so the environment is built
without the manifold check of :meth:`Environment.from_meshes`.

Cost: two triangles per boundary face. The lab's ``collapse-segmentation`` voxel file (110,286
occupied cells of 0.6 mm in a 512³ grid, a shell about one cell thick) has 220,582 boundary
faces, 441,164 triangles, some 40 times the chest mesh.
"""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array
from riskplan.collision.environment import Environment
from riskplan.errors import InvalidInputError

__all__ = ["voxel_boundary_mesh", "voxel_environment", "voxels_contain"]


def _check_cells(occupied, origin, spacing):
    occ = np.asarray(occupied)
    if occ.ndim != 2 or occ.shape[1] != 3 or not np.issubdtype(occ.dtype, np.integer):
        raise InvalidInputError(f"occupied: expected (K, 3) integer cell indices, got {occ.shape}")
    if len(occ) == 0:
        raise InvalidInputError("occupied: no occupied cells")
    o = as_array(origin, "origin", shape=(3,))
    h = as_array(spacing, "spacing", shape=(3,))
    if np.any(h <= 0):
        raise InvalidInputError(f"spacing: must be > 0, got {h.tolist()}")
    return np.unique(occ.astype(np.int64), axis=0), o, h


def _keys(idx: np.ndarray, lo: np.ndarray, span: np.ndarray) -> np.ndarray:
    """Linear keys of integer cells ``(n, 3)`` in the box ``[lo, lo + span)``."""
    q = idx - lo
    return (q[:, 0] * span[1] + q[:, 1]) * span[2] + q[:, 2]


def voxel_boundary_mesh(occupied, origin, spacing) -> tuple[np.ndarray, np.ndarray]:
    """The closed, outward-oriented boundary surface of a union of axis-aligned cells.

    Parameters
    ----------
    occupied : (K, 3) int array
        Indices ``(i, j, k)`` of the occupied cells; cell ``(i, j, k)`` is the box
        ``origin + [i, i+1] x [j, j+1] x [k, k+1] * spacing``.
    origin : (3,) array
        Corner of cell ``(0, 0, 0)`` (m).
    spacing : (3,) array
        Cell size per axis (m).

    Returns
    -------
    vertices : (V, 3) float64
        The lattice corners the boundary faces use (m).
    faces : (2 B, 3) int64
        Two triangles per boundary face (a face between an occupied and an empty cell),
        counter-clockwise seen from outside (normal from the occupied cell into the empty one).
    """
    occ, o, h = _check_cells(occupied, origin, spacing)
    lo = occ.min(0) - 1
    span = occ.max(0) + 2 - lo
    keys = np.sort(_keys(occ, lo, span))
    quads = []
    eye = np.eye(3, dtype=np.int64)
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3  # e_b x e_c = e_a
        for sign in (1, -1):
            nb = occ + sign * eye[a]
            k = _keys(nb, lo, span)
            pos = np.searchsorted(keys, k)
            pos[pos == len(keys)] = 0
            cells = occ[keys[pos] != k]  # occupied cells whose neighbour this way is empty
            # the face's plane: x_a = i + 1 (sign +) or x_a = i (sign -)
            base = cells + (eye[a] if sign > 0 else 0)
            corners = np.stack(
                [base, base + eye[b], base + eye[b] + eye[c], base + eye[c]], axis=1
            )  # (n, 4, 3), counter-clockwise about +e_a
            quads.append(corners if sign > 0 else corners[:, ::-1])
    q = np.concatenate(quads)  # (B, 4, 3) lattice points
    lattice, inv = np.unique(q.reshape(-1, 3), axis=0, return_inverse=True)
    inv = inv.reshape(-1, 4)
    faces = np.concatenate([inv[:, [0, 1, 2]], inv[:, [0, 2, 3]]])
    return o + lattice * h, faces.astype(np.int64)


def voxel_environment(occupied, origin, spacing, *, transform=None, name="voxels") -> Environment:
    """An :class:`Environment` of one obstacle, the union of the occupied cells
    (:func:`voxel_boundary_mesh`).

    Parameters
    ----------
    occupied, origin, spacing
        As :func:`voxel_boundary_mesh`.
    transform : callable, optional
        Takes the ``(V, 3)`` vertices to the environment's frame (a rigid motion, e.g.
        :meth:`riskplan.planning.problem_voxels.VoxelEnvironment.voxel_to_robot`); a reflection
        would turn the faces inwards and is refused.
    name : str
        The obstacle's name.

    Returns
    -------
    Environment
        One solid obstacle (3-D), built without the manifold check (module docstring).
    """
    V, F = voxel_boundary_mesh(occupied, origin, spacing)
    if transform is not None:
        V0 = V
        V = np.asarray(transform(V), dtype=np.float64)
        if V.shape != V0.shape or not np.all(np.isfinite(V)):
            raise InvalidInputError("transform: must map (V, 3) vertices to finite (V, 3)")
        # a rigid motion keeps the enclosed volume's sign (one reflection would flip it)
        from riskplan.collision.geometry import signed_volume

        if signed_volume(V, F) * signed_volume(V0, F) <= 0:
            raise InvalidInputError("transform: must be a proper rigid motion (no reflection)")
    return Environment(V, F, np.zeros(len(F), dtype=np.int64), [name], validate=False)


def voxels_contain(points, occupied, origin, spacing) -> np.ndarray:
    """Whether points lie in an occupied cell (the direct test, the oracle of the surface's
    winding number).

    Parameters
    ----------
    points : (..., 3) array
        Points (m).
    occupied, origin, spacing
        As :func:`voxel_boundary_mesh`.

    Returns
    -------
    (...,) bool array
        True where the point lies in an occupied half-open cell ``[i, i+1)`` per axis.
    """
    occ, o, h = _check_cells(occupied, origin, spacing)
    P = np.asarray(points, dtype=np.float64)
    idx = np.floor((P.reshape(-1, 3) - o) / h).astype(np.int64)
    lo = occ.min(0)
    span = occ.max(0) + 1 - lo
    inside = np.all((idx >= lo) & (idx < lo + span), axis=1)
    keys = np.sort(_keys(occ, lo, span))
    k = _keys(np.where(inside[:, None], idx, lo), lo, span)
    pos = np.minimum(np.searchsorted(keys, k), len(keys) - 1)
    return (inside & (keys[pos] == k)).reshape(P.shape[:-1])
