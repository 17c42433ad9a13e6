"""The 3-D needle's tissue: a linear-elastic block on the project's tetrahedral FEM
(:class:`riskplan.deformable.TetTissue` on :func:`riskplan.deformable.tet_block`), with
what a needle step needs — a point load at the tip's material point and the displacement
at the tip and at fixed tracked material points (obstacle and target samples).

A load ``f`` at a material point ``X`` of element ``e`` with barycentric weights ``λ`` is
the consistent nodal force ``λ_a f`` on the element's nodes; one solve with the tissue's
cached factorisation (``K_ff⁻¹ f_free``) gives the nodal displacement ``u``, and the tip's
displacement ``Σ_a λ_a u_a`` and the tracked points' are P1 interpolations. The solve does
not touch the tissue's own state, so a step stays a pure function of its inputs.

The block rests on a table: its bottom face ``z = 0`` is fixed (a choice: the 2-D square is
held at its corners; a 3-D point support would be singular).
"""

from __future__ import annotations

import numpy as np

from riskplan.errors import InvalidInputError

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


class TetBlock:
    """The block ``[0, size]`` meshed with about ``n_elements`` tetrahedra
    (:func:`~riskplan.deformable.tet_block`), its bottom face fixed, and the interpolation
    of the ``tracked (k, 3)`` material points (each must lie in the block)."""

    def __init__(self, size, n_elements: int, tracked):
        from riskplan.deformable import tet_block
        from riskplan.deformable.tissue3d import locate3d

        self.size = np.asarray(size, dtype=np.float64)
        self.mesh = tet_block(self.size, int(n_elements))
        self.grid = grid_for(self.size, n_elements)
        self.tets = self.mesh.tets
        self.n_nodes = self.mesh.n_nodes
        self.n_elements = self.mesh.n_elements
        self.fixed_nodes = self.mesh.face_nodes("z-")
        tr = np.asarray(tracked, dtype=np.float64).reshape(-1, 3)
        try:
            self.interp = locate3d(self.mesh, tr, "tracked points (obstacle and target samples)")
        except InvalidInputError as exc:
            raise InvalidInputError(f"{exc} (they must lie inside the tissue block)") from exc
        self.tracked = tr
        self._base = None

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
        X = np.asarray(X, dtype=np.float64)
        return bool(np.all(X >= 0.0) and np.all(X <= self.size))

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
        from riskplan.deformable.tissue3d import find_points

        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        return find_points(self.mesh, pts)

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
        element ``e`` with barycentric weights ``lam (4,)``.

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
