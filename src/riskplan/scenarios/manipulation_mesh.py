"""Per-mesh data of the manipulation scenario (:mod:`riskplan.scenarios.manipulation`): the
mesh of the object, its fixed nodes, the manipulators' patch weights, the interpolation of the
target and sensed points, and the boundary loop with the weights that move it with the sensed
points (what LQG-MP checks against the obstacle)."""

from __future__ import annotations

import numpy as np

from riskplan.errors import InvalidInputError

# the scenario's own per-mesh data: handed out by no package
__all__: list[str] = []


def _boundary_loop(edges: np.ndarray) -> np.ndarray:
    """Node indices of the boundary cycle, in edge order (counter-clockwise)."""
    nxt = {int(a): int(b) for a, b in edges}
    start = int(edges[0, 0])
    loop = [start]
    while True:
        n = nxt[loop[-1]]
        if n == start:
            break
        loop.append(n)
        if len(loop) > len(edges):  # pragma: no cover - a valid mesh has one boundary cycle
            raise InvalidInputError("mesh: boundary is not a single cycle")
    return np.asarray(loop, dtype=np.int64)


def _nodes_on_segment(nodes: np.ndarray, seg: np.ndarray, tol: float) -> np.ndarray:
    a, b = seg
    ab = b - a
    t = np.clip(((nodes - a) @ ab) / (ab @ ab), 0.0, 1.0)
    d = np.sqrt(((nodes - (a + t[:, None] * ab)) ** 2).sum(1))
    return np.flatnonzero(d <= tol)


class MeshData:
    """Cached per element count: mesh, fixed nodes, patch weights ``W (n_nodes, 3)``,
    interpolator for [target, sensed boundary points, manipulators], boundary loop."""

    def __init__(self, cfg, n_elements: int):
        from riskplan.deformable import locate, mesh_polygon, patch_weights

        mesh = mesh_polygon(cfg.outline, n_elements, keep_points=cfg.manipulators)
        scale = float(np.ptp(cfg.outline, axis=0).max())
        self.mesh = mesh
        self.fixed = _nodes_on_segment(mesh.nodes, cfg.fixed_segment, 1e-9 * scale)
        W = np.stack(
            [patch_weights(mesh, c, cfg.patch_radius, on="boundary") for c in cfg.manipulators],
            axis=1,
        )
        W[self.fixed] = 0.0  # load on the support is taken by it
        self.W = W
        pts = np.concatenate(
            [
                np.asarray(cfg.target, dtype=np.float64)[None],
                cfg.boundary_points(),
                cfg.manipulators,
            ]
        )
        self.interp = locate(mesh, pts)
        self.loop = _boundary_loop(mesh.boundary_edges)
        nb = cfg.n_boundary
        self.target_index = 0
        self.boundary_slice = slice(1, 1 + nb)
        self.manipulator_slice = slice(1 + nb, 1 + nb + len(cfg.manipulators))
        self.outline_weights = _outline_weights(cfg, mesh.nodes[self.loop])


def _outline_weights(cfg, ref: np.ndarray):
    """``(a, b, lam)`` for the boundary nodes ``ref (B, 2)`` (reference positions, loop
    order): each node moves with ``(1 − lam) d_a + lam d_b``, ``d_i`` the displacement of
    sensed point ``i``, interpolated by arc length between the two sensed points around it
    (``ManipulationConfig.boundary_points`` spaces them by arc length); nodes before the
    first or after the last sensed point, the fixed edge's included, follow the nearer end
    point (an over-estimate of their motion: the fixed edge does not move)."""
    n = len(cfg.outline)
    i0 = (int(cfg.fixed_edge) + 1) % n
    k0 = int(np.argmin(((ref - cfg.outline[i0]) ** 2).sum(1)))
    order = np.roll(np.arange(len(ref)), -k0)
    r = ref[order]
    s = np.concatenate([[0.0], np.cumsum(np.sqrt((np.diff(r, axis=0) ** 2).sum(1)))])
    edges = np.roll(cfg.outline, -i0, axis=0)
    free_len = float(np.sqrt((np.diff(edges, axis=0) ** 2).sum(1)).sum())
    nb = int(cfg.n_boundary)
    sp = (np.arange(nb) + 0.5) / nb * free_len
    a = np.zeros(len(ref), dtype=np.int64)
    b = np.zeros(len(ref), dtype=np.int64)
    lam = np.zeros(len(ref))
    total = s[-1] + float(np.sqrt(((r[-1] - r[0]) ** 2).sum()))
    for q, sq in zip(order, s):
        if nb > 1 and sp[0] <= sq <= sp[-1]:
            k = min(int(np.searchsorted(sp, sq, side="right")) - 1, nb - 2)
            a[q], b[q], lam[q] = k, k + 1, (sq - sp[k]) / (sp[k + 1] - sp[k])
        else:
            end = nb - 1 if sp[-1] < sq <= 0.5 * (free_len + total) else 0
            a[q] = b[q] = end
    return a, b, lam
