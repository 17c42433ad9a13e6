"""The 3-D needle's tissue: a linear-elastic block on the project's tetrahedral FEM
(:class:`riskplan.deformable.TetTissue` on :func:`riskplan.deformable.tet_block`), with
what a needle step needs — a point load at the tip's material point and the displacement
at the tip and at fixed tracked material points (obstacle and target samples).

A load ``f`` at a material point ``X`` of element ``e`` with barycentric weights ``λ`` is
the consistent nodal force ``λ_a f`` on the element's nodes; one solve with the tissue's
cached factorisation (``K_ff⁻¹ f_free``) gives the nodal displacement ``u``, and the tip's
displacement ``Σ_a λ_a u_a`` and the tracked points' are P1 interpolations. The solve does
not touch the tissue's own state, so a step stays a pure function of its inputs.

**Green's functions.** The load touches the four nodes of one element, and a step needs the
response at those four nodes and at the ``k`` tracked points only. For linear elasticity
``u = K⁻¹ f`` is exact superposition, so :meth:`TetBlockModel.point_load` uses, per
material, every element's 12 × 12 block ``G_e`` of ``K⁻¹`` (by selected inversion of the
band of the factor, :meth:`riskplan.deformable.TetTissue.element_green_blocks`: the cost
of one factorisation) and the tracked points' response ``W = K⁻¹ Cᵀ`` (``C`` their P1
interpolation; one solve with ``3k`` right-hand sides)::

    u(X) = Σ_b λ_b (G_e f_e)_b,     u(tracked) = W[e]ᵀ f_e,     f_e = λ ⊗ f (12,)

(``W[e]`` the rows of the element's twelve DOFs; ``C K⁻¹ = (K⁻¹ Cᵀ)ᵀ`` by the symmetry of
``K``). A step then costs two small products instead of a solve, on any element, and a new
material costs two factorisation-sized passes. The result is the direct solve's up to
round-off (tested against it, float64).

**Choice by use.** The block pass pays off only for a model asked about many nodes (the RRT
and the selection re-use one material over the whole tree); a single execution with its own
material draw touches a few dozen nodes once. So a model starts with the Green's columns of
each node it is asked about (:meth:`TetBlockModel.columns`, one solve with three right-hand
sides, cached) and builds the blocks once it has been asked for more than
``switch_nodes`` distinct nodes, the measured break-even ``1.2 N^{2/3}`` (``N`` nodes):
the block pass and one node's columns cost 19.6 ms and 0.36 ms on the 1296-tetrahedra mesh
(343 nodes, break-even 55), 183 ms and 1.36 ms at 5040 (1144 nodes, 134), CPU time, medians
of three materials, 2-core AMD EPYC shared with other jobs; both grow with the band, the
block pass by one power of it more. Switching at the break-even costs at most twice the
better of the two for any number of nodes. Both paths give the direct solve's result up to
round-off (tested). Locating the tip uses the block's grid: the six
tetrahedra of the grid cell holding the point are tried first (the general search only if
round-off puts it in none of them).

The block rests on a table: its bottom face ``z = 0`` is fixed (a choice: the 2-D square is
held at its corners; a 3-D point support would be singular).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from riskplan.errors import InvalidInputError, SimulationError

__all__ = ["TetBlock", "TetBlockModel", "grid_for"]


def grid_for(size, n_elements: int) -> tuple[int, int, int]:
    """Cells per axis ``(nx, ny, nz)`` of the block mesh for about ``n_elements`` tetrahedra
    (:func:`riskplan.deformable.tetmesh.grid_shape`).

    Parameters
    ----------
    size : array_like, shape (3,)
        The block's edge lengths.
    n_elements : int
        The requested number of tetrahedra.

    Returns
    -------
    tuple of int
        ``(nx, ny, nz)``, cells per axis.
    """
    from riskplan.deformable.tetmesh import grid_shape

    return tuple(int(n) for n in grid_shape(np.asarray(size, dtype=np.float64), int(n_elements)))


def _switch_nodes(n_nodes: int) -> int:
    """Distinct loaded nodes after which a :class:`TetBlockModel` builds every element's
    block of ``K⁻¹`` instead of per-node Green's columns: the measured break-even
    ``round(1.2 N^{2/3})`` (module docstring; 59 on the 1296-tetrahedra mesh, 131 at 5040).

    Parameters
    ----------
    n_nodes : int
        Nodes ``N`` of the block mesh.

    Returns
    -------
    int
        The number of distinct nodes.
    """
    return round(1.2 * float(n_nodes) ** (2.0 / 3.0))


class TetBlock:
    """The block ``[0, size]`` meshed with about ``n_elements`` tetrahedra
    (:func:`~riskplan.deformable.tet_block`), its bottom face fixed, and the interpolation
    of the ``tracked (k, 3)`` material points (each must lie in the block)."""

    def __init__(self, size, n_elements: int, tracked):
        from riskplan.deformable import tet_block
        from riskplan.deformable.tetlocate import locate3d

        self.size = np.asarray(size, dtype=np.float64)
        self._size_tuple = tuple(float(v) for v in self.size)
        self.mesh = tet_block(self.size, int(n_elements))
        self.grid = grid_for(self.size, n_elements)
        self.tets = self.mesh.tets
        self.n_nodes = self.mesh.n_nodes
        self.n_elements = self.mesh.n_elements
        #: ``(T, 12)`` the DOFs of each tetrahedron (interleaved)
        self.element_dofs = (3 * self.tets[:, :, None] + np.arange(3)).reshape(-1, 12)
        self.fixed_nodes = self.mesh.face_nodes("z-")
        tr = np.asarray(tracked, dtype=np.float64).reshape(-1, 3)
        try:
            self.interp = locate3d(self.mesh, tr, "tracked points (obstacle and target samples)")
        except InvalidInputError as exc:
            raise InvalidInputError(f"{exc} (they must lie inside the tissue block)") from exc
        self.tracked = tr
        self._base = None
        # the grid cell of every tetrahedron (its centroid's cell): a point is located by
        # its cell's tetrahedra (the Kuhn split puts six in each)
        g = self._grid = np.asarray(self.grid, dtype=np.int64)
        cell = np.minimum((self.mesh.centroids / (self.size / g)).astype(np.int64), g - 1)
        flat = (cell[:, 0] * g[1] + cell[:, 1]) * g[2] + cell[:, 2]
        order = np.argsort(flat, kind="stable")
        counts = np.bincount(flat, minlength=int(np.prod(g)))
        if counts.min() == counts.max():  # a regular split: (cells, 6) table
            self._cell_tets = np.ascontiguousarray(order.reshape(len(counts), -1))
            self._cell_maps = np.ascontiguousarray(self.mesh.barycentric_maps[self._cell_tets])
        else:  # pragma: no cover - tet_block always splits each cell alike
            self._cell_tets = None

    def contains(self, X) -> bool:
        """Whether the material point ``X (3,)`` lies in the block (closed).

        Parameters
        ----------
        X : array_like, shape (3,)
            The material point.

        Returns
        -------
        bool
            Whether it lies in ``[0, size]``.
        """
        X = np.asarray(X, dtype=np.float64).reshape(3)
        sx, sy, sz = self._size_tuple
        return bool(0.0 <= X[0] <= sx and 0.0 <= X[1] <= sy and 0.0 <= X[2] <= sz)  # NaN: False

    def locate(self, points) -> tuple[np.ndarray, np.ndarray]:
        """``(elem (k,), lam (k, 4))``: containing tetrahedra (``−1`` outside) and
        barycentric weights (:func:`riskplan.deformable.tetlocate.find_points`).

        Parameters
        ----------
        points : array_like, shape (k, 3)
            Material points.

        Returns
        -------
        elem : numpy.ndarray, shape (k,)
            Index of the containing tetrahedron (``−1`` outside).
        lam : numpy.ndarray, shape (k, 4)
            Barycentric weights in it.
        """
        from riskplan.deformable.tetlocate import find_points

        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        if self._cell_tets is not None and len(pts) == 1 and self.contains(pts[0]):
            hit = self._locate_in_cell(pts[0])
            if hit is not None:
                return hit
        return find_points(self.mesh, pts)

    def locate_point(self, X) -> tuple[int, np.ndarray]:
        """``(elem, lam (4,))`` of one material point inside the block (a simulator step's
        hot path: :meth:`locate` without its checks; the point must lie in the block,
        :meth:`contains`; a point outside raises :class:`~riskplan.errors.InvalidInputError`,
        a point inside that round-off puts in no tetrahedron
        :class:`~riskplan.errors.SimulationError`, a simulator failure the RRT counts).

        Parameters
        ----------
        X : numpy.ndarray, shape (3,)
            The material point.

        Returns
        -------
        elem : int
            The containing tetrahedron.
        lam : numpy.ndarray, shape (4,)
            Its barycentric weights.
        """
        X = np.ascontiguousarray(X, dtype=np.float64)
        if self._cell_tets is not None:
            hit = self._locate_in_cell(X)
            if hit is not None:
                return int(hit[0][0]), hit[1][0]
        # round-off between the cell's tetrahedra (rare), or a point outside
        if not self.contains(X):
            raise InvalidInputError(f"X: {X.tolist()} lies outside the tissue block")
        elem, lam = self.locate(X)
        if elem[0] < 0:
            # inside by `contains` but in no tetrahedron by round-off: a failed simulator
            # step (the RRT discards the edge, an execution ends), not a caller's error
            raise SimulationError(f"X: {X.tolist()} lies in the block but in no tetrahedron")
        return int(elem[0]), lam[0]

    def _locate_in_cell(self, X: np.ndarray):
        """The tetrahedron of the grid cell holding ``X`` with the largest smallest
        barycentric weight, if that weight is ``>= −INSIDE_TOL`` (else ``None``;
        :func:`riskplan.deformable.tetlocate.locate_in_grid`)."""
        from riskplan.deformable.tetlocate import INSIDE_TOL, locate_in_grid

        e, lam = locate_in_grid(
            X, self.size, self._grid, self._cell_tets, self._cell_maps, INSIDE_TOL
        )
        if e < 0:
            return None
        return np.array([e]), lam[None, :]

    def model(self, youngs_modulus: float, poissons_ratio: float) -> TetBlockModel:
        """The factorised model of one isotropic material (the first material builds the
        tissue; later ones re-use its assembly, :meth:`TetTissue.with_material`).

        Parameters
        ----------
        youngs_modulus : float
            Young's modulus E.
        poissons_ratio : float
            Poisson's ratio ν.

        Returns
        -------
        TetBlockModel
            The factorised linear-elastic model.
        """
        from riskplan.deformable import Material, TetTissue

        mat = Material(float(youngs_modulus), float(poissons_ratio))
        if self._base is None:
            self._base = TetTissue(self.mesh, mat, self.fixed_nodes)
            tissue = self._base
        else:
            tissue = self._base.with_material(mat)
        return TetBlockModel(self, tissue)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_base"] = None  # factorisations are rebuilt where they are used
        return state


class TetBlockModel:
    """One material on a :class:`TetBlock`: point loads and nodal solves with the tissue's
    cached factorisation (module docstring)."""

    def __init__(self, block: TetBlock, tissue):
        self.block = block
        self.tissue = tissue
        self._free = tissue.free_dofs
        self._columns: dict = {}
        self._elements: dict = {}
        self._fast = None
        self._edofs = block.element_dofs
        #: distinct loaded nodes after which :meth:`point_load` switches to the blocks
        self.switch_nodes = _switch_nodes(block.n_nodes)

    def columns(self, node: int) -> tuple[np.ndarray, np.ndarray]:
        """Green's columns of ``node`` (module docstring), computed on first use.

        Parameters
        ----------
        node : int
            A node of the block.

        Returns
        -------
        G : numpy.ndarray, shape (N, 3, 3)
            ``G[b, j, i]``: displacement component ``j`` of node ``b`` under a unit force
            in direction ``i`` at ``node`` (zero for a node of the fixed face).
        CG : numpy.ndarray, shape (k, 3, 3)
            The same at the tracked points (their P1 interpolation of ``G``).
        """
        hit = self._columns.get(node)
        if hit is not None:
            return hit
        b = self.block
        n = 3 * b.n_nodes
        E = np.zeros((n, 3))
        E[3 * node + np.arange(3), np.arange(3)] = 1.0
        u = np.zeros((n, 3))
        if np.any(E[self._free]):
            u[self._free] = self.tissue.solve_linear_free(np.ascontiguousarray(E[self._free]))
        G = u.reshape(b.n_nodes, 3, 3)
        ip = b.interp
        CG = np.einsum("pcji,pc->pji", G[ip.node_index], ip.weights)
        self._columns[node] = hit = (G, CG)
        return hit

    def solve(self, nodal_forces) -> np.ndarray:
        """Displacement ``(N, 3)`` for nodal forces ``(N, 3)`` (zero on the fixed face; a
        force there is taken by the support).

        Parameters
        ----------
        nodal_forces : array_like, shape (N, 3)
            Force on each node.

        Returns
        -------
        numpy.ndarray, shape (N, 3)
            The nodal displacement.
        """
        f = np.asarray(nodal_forces, dtype=np.float64).reshape(-1)
        u = np.zeros(f.shape[0])
        u[self._free] = self.tissue.solve_linear_free(f[self._free])
        return u.reshape(-1, 3)

    def point_load(self, e: int, lam, force) -> tuple[np.ndarray, np.ndarray]:
        """``(u(X) (3,), u(tracked) (k, 3))`` for the force ``force (3,)`` at the point of
        element ``e`` with barycentric weights ``lam (4,)`` (module docstring: the Green's
        columns of its nodes, or, past ``switch_nodes`` distinct nodes, the element's block of
        ``K⁻¹`` and the tracked points' response ``W = K⁻¹ Cᵀ``).

        Parameters
        ----------
        e : int
            The element holding the loaded point.
        lam : array_like, shape (4,)
            The point's barycentric weights in it.
        force : array_like, shape (3,)
            The force.

        Returns
        -------
        u_point : numpy.ndarray, shape (3,)
            The displacement at the loaded point.
        u_tracked : numpy.ndarray, shape (k, 3)
            The displacement of the block's tracked points.
        """
        lam = np.ascontiguousarray(lam, dtype=np.float64).reshape(4)
        f = np.ascontiguousarray(force, dtype=np.float64).reshape(3)
        e = int(e)
        if self._fast is None and not self._past_break_even(e):
            Ge, CGe = self._element(e)
            fa = np.outer(lam, f).reshape(12)  # nodal forces λ_a f
            return lam @ (Ge @ fa).reshape(4, 3), (CGe @ fa).reshape(-1, 3)
        G, W = self._green()
        u, tracked = _point_load_kernel(G, W, self._edofs, e, lam, f)
        return u, tracked.reshape(-1, 3)

    @property
    def uses_blocks(self) -> bool:
        """Whether :meth:`point_load` has switched to every element's block of ``K⁻¹``."""
        return self._fast is not None

    def _past_break_even(self, e: int) -> bool:
        """Whether loading element ``e`` takes the distinct nodes asked for past
        ``switch_nodes`` (then the per-node caches are dropped)."""
        new = sum(int(a) not in self._columns for a in self.block.tets[e])
        if len(self._columns) + new <= self.switch_nodes:
            return False
        self._columns.clear()
        self._elements.clear()
        return True

    def _element(self, e: int) -> tuple[np.ndarray, np.ndarray]:
        """``(G_e (12, 12), C G_e (3k, 12))``: the response of element ``e``'s nodes and of
        the tracked points to its twelve nodal force components (the Green's columns of its
        four nodes, superposed; cached per element)."""
        hit = self._elements.get(e)
        if hit is not None:
            return hit
        nodes = self.block.tets[e]
        cols = [self.columns(int(a)) for a in nodes]
        # G_e[(b, j), (a, i)] = G_a[nodes[b], j, i]
        Ge = np.stack([G[nodes] for G, _ in cols], axis=2).reshape(12, 12)
        CGe = np.stack([CG for _, CG in cols], axis=2).reshape(-1, 12)
        self._elements[e] = hit = (Ge, CGe)
        return hit

    def _green(self) -> tuple[np.ndarray, np.ndarray]:
        """``(G (T, 12, 12), W (3N, 3k))``: every element's block of ``K⁻¹``
        (:meth:`riskplan.deformable.TetTissue.element_green_blocks`) and the tracked
        points' response to a unit force at each DOF, ``W = K⁻¹ Cᵀ`` (``C (3k, 3N)`` their
        P1 interpolation; by the symmetry of ``K⁻¹``, column ``3p + j`` of ``W`` is also
        component ``j`` at point ``p`` under each unit force): one solve with ``3k``
        right-hand sides. Computed on first use."""
        hit = self._fast
        if hit is None:
            b = self.block
            ip = b.interp
            k = ip.node_index.shape[0]
            n = 3 * b.n_nodes
            Ct = np.zeros((n, 3 * k))
            comp = np.arange(3)
            rows = 3 * ip.node_index[:, :, None] + comp  # (k, 4, 3)
            cols = np.broadcast_to(3 * np.arange(k)[:, None, None] + comp, rows.shape)
            np.add.at(Ct, (rows, cols), np.broadcast_to(ip.weights[:, :, None], rows.shape))
            W = np.zeros((n, 3 * k))
            W[self._free] = self.tissue.solve_linear_free(np.ascontiguousarray(Ct[self._free]))
            self._fast = hit = (self.tissue.element_green_blocks(), W)
        return hit

    def point_load_direct(self, e: int, lam, force) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`point_load` by one solve of the whole system (the reference the Green's
        columns are tested against).

        Parameters
        ----------
        e : int
            The element holding the loaded point.
        lam : array_like, shape (4,)
            The point's barycentric weights in it.
        force : array_like, shape (3,)
            The force.

        Returns
        -------
        u_point : numpy.ndarray, shape (3,)
            The displacement at the loaded point.
        u_tracked : numpy.ndarray, shape (k, 3)
            The displacement of the block's tracked points.
        """
        b = self.block
        lam = np.asarray(lam, dtype=np.float64)
        F = np.zeros((b.n_nodes, 3))
        F[b.tets[e]] = np.outer(lam, np.asarray(force, dtype=np.float64))
        u = self.solve(F)
        return lam @ u[b.tets[e]], b.interp.interpolate(u)


@nb.njit(cache=True)
def _point_load_kernel(G, W, edofs, e, lam, force):
    """:meth:`TetBlockModel.point_load`'s sums, compiled: ``f_e = λ ⊗ f``,
    ``u(X) = Σ_b λ_b (G_e f_e)_b``, ``u(tracked) = W[e]ᵀ f_e`` (flat ``(3k,)``)."""
    fa = np.empty(12)
    for a in range(4):
        for i in range(3):
            fa[3 * a + i] = lam[a] * force[i]
    u = np.zeros(3)
    for b in range(4):
        for j in range(3):
            s = 0.0
            for q in range(12):
                s += G[e, 3 * b + j, q] * fa[q]
            u[j] += lam[b] * s
    tracked = np.zeros(W.shape[1])
    for q in range(12):
        row = edofs[e, q]
        fq = fa[q]
        for c in range(W.shape[1]):
            tracked[c] += fq * W[row, c]
    return u, tracked
