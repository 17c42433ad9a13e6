"""Linear elastic FEM (P1 triangles) with a cached factorisation (paper V-A: "an isotropic,
linearly elastic material and ... a linear FEM simulator").

Weak form: find u ∈ V (u = ū on the fixed nodes) with

    ∫_Ω σ(u) : ε(v) dx = Σ_a f_a · v(X_a)     for all v ∈ V₀,
    ε(u) = ½(∇u + ∇uᵀ),  σ = λ₂ tr(ε) I + 2 μ ε,

assembled with scikit-fem (``ElementVector(ElementTriP1())``, interleaved DOFs
``[u_x0, u_y0, u_x1, ...]``, so ``u.reshape(N, 2)`` is the nodal displacement). The
stiffness is kept as ``K = λ₂ K_λ + μ K_μ``, so a new material costs one factorisation
and no re-assembly (:meth:`LinearElasticModel.with_material`).
"""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array
from riskplan.deformable.assembly import assemble_stiffness_parts, fixed_node_array, split_dofs
from riskplan.deformable.banded import banded_cholesky
from riskplan.deformable.material import Material
from riskplan.deformable.mesh import TissueMesh
from riskplan.errors import ConvergenceError, InvalidInputError
from riskplan.threads import one_blas_thread

#: Free-DOF count up to which the reduced stiffness is inverted densely (a dense
#: mat-vec beats banded triangular solves for small systems); above it an RCM-ordered
#: banded Cholesky factorisation is used (SuperLU if that fails).
DENSE_MAX_DOFS = 700


class LinearElasticModel:
    """Linear elasticity on ``mesh`` with the nodes ``fixed_nodes`` held (both components).

    Parameters
    ----------
    mesh: :class:`TissueMesh`
    material: :class:`Material`
    fixed_nodes: ``(F,)`` node indices with prescribed displacement (zero unless given
        per solve).

    Attributes: ``K`` (2N×2N CSR stiffness), ``free_dofs``, ``fixed_dofs`` (flat,
    interleaved), ``fixed_nodes``.
    """

    def __init__(self, mesh: TissueMesh, material: Material, fixed_nodes, *, _parts=None):
        if not isinstance(mesh, TissueMesh):
            raise InvalidInputError(f"mesh: expected a TissueMesh, got {type(mesh).__name__}")
        if not isinstance(material, Material):
            raise InvalidInputError(f"material: expected a Material, got {type(material).__name__}")
        self.mesh = mesh
        self.material = material
        self.fixed_nodes = fixed_node_array(fixed_nodes, mesh.n_nodes)
        if self.fixed_nodes.size == 1:
            raise InvalidInputError(
                "fixed_nodes: one fixed node leaves the rotation about it free; fix at least two distinct nodes"
            )
        self._parts = _parts if _parts is not None else assemble_stiffness_parts(mesh)
        lam, mu = material.lame
        self.K = (lam * self._parts[0] + mu * self._parts[1]).tocsr()
        n = 2 * mesh.n_nodes
        self.fixed_dofs, self.free_dofs = split_dofs(self.fixed_nodes, n)
        self._K_ff = self.K[self.free_dofs][:, self.free_dofs].tocsc()
        self._K_fc = self.K[self.free_dofs][:, self.fixed_dofs].tocsr()
        self._n = n
        self._factorise()

    def __getstate__(self):
        return {
            "mesh": self.mesh,
            "material": self.material,
            "fixed_nodes": self.fixed_nodes,
            "parts": self._parts,
        }

    def __setstate__(self, state):
        self.__init__(state["mesh"], state["material"], state["fixed_nodes"], _parts=state["parts"])

    @one_blas_thread
    def _factorise(self) -> None:
        import scipy.linalg
        from scipy.sparse.linalg import splu

        nf = len(self.free_dofs)
        singular = InvalidInputError(
            "fixed_nodes: the stiffness is singular (some part of the mesh is not held by the fixed nodes)"
        )
        if nf <= DENSE_MAX_DOFS:
            # K_ff is symmetric positive definite: Cholesky, then the explicit inverse
            try:
                c = scipy.linalg.cho_factor(self._K_ff.toarray())
            except np.linalg.LinAlgError as exc:
                raise singular from exc
            self._inv = scipy.linalg.cho_solve(c, np.eye(nf))
            self._lu_solve = None
        else:
            self._inv = None
            try:
                self._lu_solve = banded_cholesky(self._K_ff)
            except np.linalg.LinAlgError:
                try:
                    self._lu_solve = splu(self._K_ff).solve
                except RuntimeError as exc:
                    raise singular from exc

    # ---- construction helpers -------------------------------------------------------
    def with_material(self, material: Material) -> LinearElasticModel:
        """The same mesh and supports with another material (re-uses the assembly).

        Parameters
        ----------
        material : Material
            Young's modulus and Poisson ratio of the new model.

        Returns
        -------
        LinearElasticModel
        """
        return LinearElasticModel(self.mesh, material, self.fixed_nodes, _parts=self._parts)

    @property
    def n_dofs(self) -> int:
        return self._n

    # ---- solves ---------------------------------------------------------------------
    def solve_free(self, f_free: np.ndarray) -> np.ndarray:
        """``K_ff⁻¹ f_free``: the free DOFs' displacements (no validation: hot path).

        Parameters
        ----------
        f_free : numpy.ndarray, (n_free,) or (n_free, k)
            Forces at the free DOFs (N), one column per load case.

        Returns
        -------
        numpy.ndarray, same shape as ``f_free``
        """
        if self._inv is not None:
            return self._inv @ f_free
        return self._lu_solve(f_free)

    def solve_flat(self, f: np.ndarray) -> np.ndarray:
        """Displacement for interleaved nodal forces, zero at the fixed nodes (no validation: hot path).

        Parameters
        ----------
        f : numpy.ndarray, (2N,)
            Nodal forces ``(f_x0, f_y0, f_x1, ...)`` (N).

        Returns
        -------
        numpy.ndarray, (2N,)
        """
        u = np.zeros(self._n)
        u[self.free_dofs] = self.solve_free(f[self.free_dofs])
        return u

    def solve(self, nodal_forces, fixed_values=None) -> np.ndarray:
        r"""Solve ``K u = f`` with prescribed displacements at the fixed nodes.

        .. math:: u_f = K_{ff}^{-1} (f_f - K_{fc} \bar u)

        Parameters
        ----------
        nodal_forces : array_like, (N, 2)
            Forces at all nodes (entries at fixed nodes are ignored; see :meth:`reactions`).
        fixed_values : array_like, (F, 2), optional
            Prescribed displacements ``ū`` of ``fixed_nodes`` (in sorted node order), default zero.

        Returns
        -------
        numpy.ndarray, (N, 2)
            Displacements ``u``.
        """
        f = as_array(nodal_forces, "nodal_forces", shape=(self.mesh.n_nodes, 2)).reshape(-1)
        u = np.zeros(self._n)
        rhs = f[self.free_dofs]
        if fixed_values is not None:
            ub = as_array(fixed_values, "fixed_values", shape=(len(self.fixed_nodes), 2)).reshape(
                -1
            )
            u[self.fixed_dofs] = ub
            rhs = rhs - self._K_fc @ ub
        u[self.free_dofs] = self.solve_free(rhs)
        if not np.all(np.isfinite(u)):  # finite loads whose response overflows float64
            raise ConvergenceError(
                "linear solve: the displacement overflows float64 (loads too large for this "
                "model); no finite equilibrium",
                residual=float("inf"),
                iterations=0,
            )
        return u.reshape(-1, 2)

    def residual(self, u, nodal_forces) -> np.ndarray:
        """Out-of-balance forces ``K u − f`` at the free DOFs.

        Parameters
        ----------
        u : array_like, (N, 2)
            Displacements.
        nodal_forces : array_like, (N, 2)
            External forces ``f``.

        Returns
        -------
        numpy.ndarray, (N, 2)
            Zeros at the fixed nodes.
        """
        r = self.K @ np.asarray(u, dtype=np.float64).reshape(-1) - np.asarray(
            nodal_forces, dtype=np.float64
        ).reshape(-1)
        r[self.fixed_dofs] = 0.0
        return r.reshape(-1, 2)

    def reactions(self, u) -> np.ndarray:
        """Support reactions at the fixed nodes: ``(K u)`` there.

        Parameters
        ----------
        u : array_like, (N, 2)
            Displacements.

        Returns
        -------
        numpy.ndarray, (F, 2)
            In sorted fixed-node order.
        """
        return (self.K @ np.asarray(u, dtype=np.float64).reshape(-1))[self.fixed_dofs].reshape(
            -1, 2
        )

    def energy(self, u) -> float:
        """Strain energy ``½ uᵀ K u``.

        Parameters
        ----------
        u : array_like, (N, 2)
            Displacements.

        Returns
        -------
        float
        """
        x = np.asarray(u, dtype=np.float64).reshape(-1)
        return 0.5 * float(x @ (self.K @ x))


def element_strains(mesh: TissueMesh, u) -> np.ndarray:
    """Small strains ``ε = sym ∇u`` (constant per P1 element).

    Parameters
    ----------
    mesh : TissueMesh
        The triangle mesh (``T`` elements, ``N`` nodes).
    u : array_like, (N, 2)
        Nodal displacements.

    Returns
    -------
    numpy.ndarray, (T, 2, 2)
    """
    G = mesh.shape_gradients  # (T, 3, 2)
    grad = np.einsum("tai,taj->tij", np.asarray(u, dtype=np.float64)[mesh.triangles], G)
    return 0.5 * (grad + np.swapaxes(grad, 1, 2))


def element_stresses(mesh: TissueMesh, material: Material, u) -> np.ndarray:
    r"""Linear stresses per element.

    .. math:: \sigma = \lambda_2 \operatorname{tr}(\varepsilon) I + 2 \mu \varepsilon

    Parameters
    ----------
    mesh : TissueMesh
        The triangle mesh.
    material : Material
        Its Lamé parameters ``(λ₂, μ)`` (plane stress or strain).
    u : array_like, (N, 2)
        Nodal displacements.

    Returns
    -------
    numpy.ndarray, (T, 2, 2)
    """
    eps = element_strains(mesh, u)
    lam, mu = material.lame
    tr = eps[:, 0, 0] + eps[:, 1, 1]
    return 2.0 * mu * eps + lam * tr[:, None, None] * np.eye(2)
