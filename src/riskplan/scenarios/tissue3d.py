"""A linear-elastic block of tetrahedra for the 3-D needle (:mod:`riskplan.scenarios.needle3d`):
scikit-fem ``MeshTet`` P1 elasticity with a factorised stiffness per material, point loads
spread by the barycentric weights of their element, and the displacement at fixed material
points.

Weak form as in 2-D (:mod:`riskplan.deformable.linear`), in 3-D: find ``u`` (zero on the
fixed face) with ``∫ σ(u) : ε(v) dX = Σ_a f_a · v(X_a)``, ``σ = λ tr(ε) I + 2 μ ε``; the
stiffness is kept as ``K = λ K_λ + μ K_μ`` so a new material is one factorisation.

What the needle needs per step is small: the displacement at its own material point ``X``
(the load point) and at the scenario's tracked material points (obstacle and target samples).
A load ``λ_a(X) f`` at element ``e`` costs one solve with the cached factorisation; both
are then P1 interpolations of the nodal displacement (``u(tracked) = P u``).

The block rests on a table: its bottom face ``z = 0`` is fixed (a choice: the 2-D square is
held at its corners; a 3-D point support would be singular).
"""

from __future__ import annotations

import numpy as np

from riskplan.errors import InvalidInputError

__all__ = ["TetBlock", "TetBlockModel", "grid_for"]


def grid_for(size, n_elements: int) -> tuple[int, int, int]:
    """Cells per axis ``(nx, ny, nz)`` of a block ``size (3,)`` meshed with about
    ``n_elements`` tetrahedra (``MeshTet.init_tensor`` splits a cell into 6), cells as
    close to cubes as the count allows."""
    size = np.asarray(size, dtype=np.float64)
    h = (float(np.prod(size)) * 6.0 / float(n_elements)) ** (1.0 / 3.0)
    return tuple(max(1, round(float(s) / h)) for s in size)


class TetBlock:
    """Mesh, stiffness parts, point location and tracked-point interpolation of a block
    ``[0, size]`` with about ``n_elements`` tetrahedra; ``tracked (k, 3)`` material points
    whose displacement every load reports (each must lie in the block)."""

    def __init__(self, size, n_elements: int, tracked):
        from skfem import Basis, ElementTetP1, ElementVector, MeshTet, asm
        from skfem.models.elasticity import linear_elasticity

        self.size = np.asarray(size, dtype=np.float64)
        nx, ny, nz = grid_for(self.size, n_elements)
        axes = [np.linspace(0.0, s, n + 1) for s, n in zip(self.size, (nx, ny, nz))]
        mesh = MeshTet.init_tensor(*axes)
        self.mesh = mesh
        self.grid = (nx, ny, nz)
        self.nodes = mesh.p.T.copy()  # (N, 3)
        self.tets = mesh.t.T.copy()  # (E, 4)
        self.n_nodes = self.nodes.shape[0]
        self.n_elements = self.tets.shape[0]
        basis = Basis(mesh, ElementVector(ElementTetP1()))
        self.K_lam = asm(linear_elasticity(1.0, 0.0), basis).tocsc()
        self.K_mu = asm(linear_elasticity(0.0, 1.0), basis).tocsc()
        #: ``(N, 3)`` the flat DOF of each node's x, y, z
        self.node_dofs = np.asarray(basis.nodal_dofs, dtype=np.int64).T.copy()
        n_dofs = 3 * self.n_nodes
        fixed_nodes = np.flatnonzero(self.nodes[:, 2] <= 1e-12 * self.size[2])
        fixed = np.zeros(n_dofs, dtype=bool)
        fixed[self.node_dofs[fixed_nodes].ravel()] = True
        self.free = np.flatnonzero(~fixed)
        self.n_dofs = n_dofs
        # element geometry for location: X = X_0 + J λ_{1..3}
        X = self.nodes[self.tets]  # (E, 4, 3)
        J = np.swapaxes(X[:, 1:] - X[:, :1], 1, 2)  # (E, 3, 3)
        # orientation is the mesher's (either sign); a degenerate element has no inverse
        vol = np.abs(np.linalg.det(J)) / 6.0
        if not np.all(vol > 1e-12 * float(np.prod(self.size)) / len(vol)):
            raise InvalidInputError(f"mesh: {int((vol <= 0).sum())} degenerate tetrahedra")
        self._X0 = X[:, 0]
        self._Jinv = np.linalg.inv(J)
        self._cell = self.size / np.array([nx, ny, nz])
        # tracked points
        tr = np.asarray(tracked, dtype=np.float64).reshape(-1, 3)
        elem, lam = self.locate(tr)
        if np.any(elem < 0):
            bad = tr[np.flatnonzero(elem < 0)[0]]
            raise InvalidInputError(f"tracked point {bad.tolist()} lies outside the tissue block")
        self.tracked = tr
        self.tracked_elem = elem
        self.tracked_lam = lam
        self._tracked_P = None

    # ---- geometry -----------------------------------------------------------------
    def contains(self, X) -> bool:
        """Whether the material point ``X (3,)`` lies in the block (closed)."""
        X = np.asarray(X, dtype=np.float64)
        return bool(np.all(X >= 0.0) and np.all(X <= self.size))

    def locate(self, points) -> tuple[np.ndarray, np.ndarray]:
        """``(elem (k,), lam (k, 4))``: the tetrahedron holding each material point and its
        barycentric weights (``elem = −1`` outside the block). The structured grid gives the
        cell; its six tetrahedra are tested (closed, with a 1e-12 slack)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        k = pts.shape[0]
        elem = np.full(k, -1, dtype=np.int64)
        lam = np.zeros((k, 4))
        nx, ny, nz = self.grid
        for i in range(k):
            x = pts[i]
            if not self.contains(x):
                continue
            c = np.minimum((x / self._cell).astype(np.int64), [nx - 1, ny - 1, nz - 1])
            e, w = self._search(x, c)
            elem[i], lam[i] = e, w
        return elem, lam

    def _search(self, x, c):
        cand = self._cell_tets(c)
        best, best_w, best_min = -1, None, -np.inf
        for e in cand:
            l3 = self._Jinv[e] @ (x - self._X0[e])
            w = np.array([1.0 - l3.sum(), *l3])
            m = w.min()
            if m >= -1e-12:
                return int(e), np.clip(w, 0.0, None) / np.clip(w, 0.0, None).sum()
            if m > best_min:
                best, best_w, best_min = int(e), w, m
        # on a face shared with a neighbouring cell (rounding): the least-outside element
        return best, np.clip(best_w, 0.0, None) / np.clip(best_w, 0.0, None).sum()

    def _cell_tets(self, c):
        cache = getattr(self, "_cell_index", None)
        if cache is None:
            centroid = self.nodes[self.tets].mean(axis=1)
            nx, ny, nz = self.grid
            ci = np.minimum((centroid / self._cell).astype(np.int64), [nx - 1, ny - 1, nz - 1])
            key = (ci[:, 0] * ny + ci[:, 1]) * nz + ci[:, 2]
            order = np.argsort(key, kind="stable")
            starts = np.searchsorted(key[order], np.arange(nx * ny * nz + 1))
            cache = self._cell_index = (order, starts)
        order, starts = cache
        nx, ny, nz = self.grid
        key = (int(c[0]) * ny + int(c[1])) * nz + int(c[2])
        return order[starts[key] : starts[key + 1]]

    def element_dofs(self, e: int) -> np.ndarray:
        """``(12,)`` flat DOFs of element ``e``'s nodes, node-major (x, y, z of node 0, ...)."""
        return self.node_dofs[self.tets[e]].ravel()

    def tracked_matrix(self):
        """Sparse ``P (3k, n_dofs)``: the displacement of the tracked points is ``P u``."""
        if self._tracked_P is None:
            from scipy.sparse import csr_matrix

            k = self.tracked.shape[0]
            rows, cols, vals = [], [], []
            for i in range(k):
                nodes = self.tets[self.tracked_elem[i]]
                for a in range(4):
                    for d in range(3):
                        rows.append(3 * i + d)
                        cols.append(self.node_dofs[nodes[a], d])
                        vals.append(self.tracked_lam[i, a])
            self._tracked_P = csr_matrix((vals, (rows, cols)), shape=(3 * k, self.n_dofs))
        return self._tracked_P

    def model(self, youngs_modulus: float, poissons_ratio: float) -> TetBlockModel:
        """The factorised model of one isotropic material."""
        return TetBlockModel(self, youngs_modulus, poissons_ratio)


class TetBlockModel:
    """One material on a :class:`TetBlock`: the factorised ``K_ff`` (SuperLU) and the
    response to a point load (module docstring)."""

    def __init__(self, block: TetBlock, youngs_modulus: float, poissons_ratio: float):
        from scipy.sparse.linalg import splu

        E, nu = float(youngs_modulus), float(poissons_ratio)
        lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
        mu = E / (2.0 * (1.0 + nu))
        self.block = block
        K = (lam * block.K_lam + mu * block.K_mu).tocsc()
        f = block.free
        self._lu = splu(K[f][:, f].tocsc())

    def solve(self, nodal_forces) -> np.ndarray:
        """Displacement ``(N, 3)`` for nodal forces ``(N, 3)`` (zero on the fixed face; a
        force there is taken by the support)."""
        b = self.block
        F = np.asarray(nodal_forces, dtype=np.float64).reshape(b.n_nodes, 3)
        flat = np.zeros(b.n_dofs)
        flat[b.node_dofs.ravel()] = F.ravel()
        u = np.zeros(b.n_dofs)
        u[b.free] = self._lu.solve(flat[b.free])
        return u[b.node_dofs]

    def point_load(self, e: int, lam, force) -> tuple[np.ndarray, np.ndarray]:
        """``(u(X) (3,), u(tracked) (k, 3))`` for the force ``force (3,)`` at the point of
        element ``e`` with barycentric weights ``lam (4,)`` (consistent nodal forces
        ``λ_a f``): one solve, then P1 interpolation."""
        b = self.block
        lam = np.asarray(lam, dtype=np.float64)
        flat = np.zeros(b.n_dofs)
        flat[b.element_dofs(e)] = np.outer(lam, np.asarray(force, dtype=np.float64)).ravel()
        u = np.zeros(b.n_dofs)
        u[b.free] = self._lu.solve(flat[b.free])
        tracked = (b.tracked_matrix() @ u).reshape(-1, 3)
        return lam @ u[b.node_dofs[b.tets[e]]], tracked
