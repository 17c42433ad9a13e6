"""Assembly for P1 triangles: element force vectors and stiffness matrices, the
degree-of-freedom bookkeeping of fixed nodes, and the sparse layouts the solvers fill.

DOFs are interleaved, ``[u_x0, u_y0, u_x1, ...]``; element DOFs are ordered ``(a, i)``
(node ``a`` of the triangle, component ``i``). Internal forces
``f_int,a = Σ_e A_e P_e ∇N_a`` and tangent ``K_{ai,bk} = Σ_e A_e ∂P_iJ/∂F_kL ∇N_aJ ∇N_bL``
(total Lagrangian form, paper V-B); the linear stiffness is assembled by scikit-fem.
"""

from __future__ import annotations

import numpy as np

from riskplan.deformable.banded import band_layout
from riskplan.deformable.mesh import TissueMesh
from riskplan.errors import InvalidInputError, require


def element_forces(P: np.ndarray, G: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Internal forces ``(T, 3, 2)``: ``f_{a,i} = A_e Σ_J P_iJ ∇N_aJ``."""
    return np.matmul(G, np.swapaxes(P, 1, 2)) * areas[:, None, None]


def element_tangents(A: np.ndarray, G: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Element stiffness ``(T, 6, 6)`` in local DOF order ``(a, i)``:
    ``K_{ai,bk} = A_e Σ_JL A_iJkL ∇N_aJ ∇N_bL`` (any law, from its 4th-order tangent)."""
    T = len(areas)
    X = np.matmul(A.reshape(T, 8, 2), np.swapaxes(G, 1, 2))  # (T, (i,J,k), b)
    X = X.reshape(T, 2, 2, 2, 3).transpose(0, 2, 1, 3, 4).reshape(T, 2, 12)  # (T, J, (i,k,b))
    K = np.matmul(G, X) * areas[:, None, None]  # (T, a, (i,k,b))
    return K.reshape(T, 3, 2, 2, 3).transpose(0, 1, 2, 4, 3).reshape(T, 6, 6)


def neohookean_element_tangents(
    Finv: np.ndarray, lnJ: np.ndarray, G: np.ndarray, areas: np.ndarray, lam: float, mu: float
) -> np.ndarray:
    """Neo-Hookean element stiffness ``(T, 6, 6)`` without forming the 4th-order tangent.

    With ``h_a = F⁻ᵀ ∇N_a`` the tangent contracts to
    ``K_{ai,bk} = A_e [μ δ_ik ∇N_a·∇N_b + λ h_ai h_bk + (μ − λ ln J) h_bi h_ak]``
    (equal to :func:`element_tangents` of ``laws.neohookean_energy_stress``'s ``A``).
    """
    T = len(areas)
    h = np.matmul(G, Finv).reshape(T, 6)  # h[t, (a,i)] = Σ_J G_aJ Finv_Ji
    O = h[:, :, None] * h[:, None, :]  # (T, (a,i), (b,k)): h_ai h_bk
    swapped = O.reshape(T, 3, 2, 3, 2).transpose(0, 3, 2, 1, 4).reshape(T, 6, 6)  # h_bi h_ak
    GG = np.matmul(G, np.swapaxes(G, 1, 2))  # (T, a, b)
    K = lam * O + (mu - lam * lnJ)[:, None, None] * swapped
    K[:, 0::2, 0::2] += mu * GG
    K[:, 1::2, 1::2] += mu * GG
    return K * areas[:, None, None]


def assemble_stiffness_parts(mesh: TissueMesh):
    """``(K_λ, K_μ)``: the P1 stiffness matrices ``(2N, 2N)`` (CSR) for ``λ=1, μ=0`` and
    ``λ=0, μ=1`` (so ``K = λ K_λ + μ K_μ``), assembled with scikit-fem."""
    skfem = require("skfem", "fem")
    from skfem.models.elasticity import linear_elasticity

    basis = skfem.Basis(mesh.to_skfem(), skfem.ElementVector(skfem.ElementTriP1()), intorder=1)
    K_lam = skfem.asm(linear_elasticity(1.0, 0.0), basis).tocsr()
    K_mu = skfem.asm(linear_elasticity(0.0, 1.0), basis).tocsr()
    return K_lam, K_mu


def fixed_node_array(fixed_nodes, n_nodes: int) -> np.ndarray:
    """Sorted unique fixed node indices ``(F,)``; raises :class:`InvalidInputError` when
    none is given or one is out of range."""
    fixed = (
        np.unique(np.asarray(fixed_nodes, dtype=np.int64).reshape(-1))
        if fixed_nodes is not None
        else None
    )
    if fixed is None or fixed.size == 0:
        raise InvalidInputError(
            "fixed_nodes: at least one node must be fixed (else rigid motions are free)"
        )
    if fixed.min() < 0 or fixed.max() >= n_nodes:
        raise InvalidInputError(f"fixed_nodes: indices must lie in [0, {n_nodes - 1}]")
    return fixed


def split_dofs(fixed_nodes: np.ndarray, n_dofs: int):
    """``(fixed_dofs, free_dofs)``: sorted flat DOF indices of the fixed nodes (both
    components) and of all other DOFs."""
    mask = np.ones(n_dofs, dtype=bool)
    fixed_dofs = np.sort(np.concatenate([2 * fixed_nodes, 2 * fixed_nodes + 1]))
    mask[fixed_dofs] = False
    return fixed_dofs, np.flatnonzero(mask)


class TangentPattern:
    """Index maps from the ``T·36`` element-matrix entries of a mesh to (a) the reduced
    CSC matrix over ``free_dofs`` and (b) the upper band of its reverse Cuthill-McKee
    permuted form (the layout of ``scipy.linalg.cholesky_banded``). Entries touching a
    fixed DOF, and for (b) lower-triangle entries, are dropped. Built once per model, so a
    Newton iteration assembles with two ``bincount`` calls.

    Attributes: ``element_dofs (T, 6)``, ``band_perm (n_free,)`` (the RCM order),
    ``bandwidth``.
    """

    def __init__(self, triangles: np.ndarray, free_dofs: np.ndarray, n_dofs: int):
        from scipy import sparse

        dofs = (2 * triangles[:, :, None] + np.arange(2)[None, None, :]).reshape(-1, 6)  # (T, 6)
        self.element_dofs = dofs
        self.n_dofs = n_dofs
        nf = len(free_dofs)
        red = np.full(n_dofs, -1, dtype=np.int64)
        red[free_dofs] = np.arange(nf)
        r = red[np.repeat(dofs, 6, axis=1)].ravel()
        c = red[np.tile(dofs, (1, 6))].ravel()
        keep = (r >= 0) & (c >= 0)
        r, c = r[keep], c[keep]
        key = c * nf + r  # CSC order: by column, then row
        uniq, slot = np.unique(key, return_inverse=True)
        self._keep = np.flatnonzero(keep)
        self._slot = slot.ravel()
        self._nnz = len(uniq)
        self._csc_shape = (nf, nf)
        self._csc_indices = (uniq % nf).astype(np.int32)
        self._csc_indptr = np.searchsorted(uniq // nf, np.arange(nf + 1)).astype(np.int32)
        pattern = sparse.csc_matrix(
            (np.ones(self._nnz), self._csc_indices, self._csc_indptr), shape=self._csc_shape
        )
        self.band_perm, bw, upper, self._band_slot = band_layout(pattern, r, c, nf)
        self.bandwidth = bw
        self._band_sel = self._keep[upper]
        self._band_size = (bw + 1) * nf

    def csc(self, Ke_flat: np.ndarray):
        """Reduced ``(n_free, n_free)`` CSC matrix from element matrices ``(T·36,)``."""
        from scipy import sparse

        data = np.bincount(self._slot, Ke_flat[self._keep], minlength=self._nnz)
        return sparse.csc_matrix((data, self._csc_indices, self._csc_indptr), shape=self._csc_shape)

    def banded(self, Ke_flat: np.ndarray) -> np.ndarray:
        """Upper band ``(bandwidth + 1, n_free)`` of the RCM-permuted reduced matrix."""
        ab = np.bincount(self._band_slot, Ke_flat[self._band_sel], minlength=self._band_size)
        return ab.reshape(self.bandwidth + 1, -1)

    def full_csr(self, Ke: np.ndarray):
        """The ``(2N, 2N)`` CSR matrix over all DOFs from element matrices ``(T, 6, 6)``."""
        from scipy import sparse

        r = np.repeat(self.element_dofs, 6, axis=1).ravel()
        c = np.tile(self.element_dofs, (1, 6)).ravel()
        return sparse.csr_matrix((Ke.ravel(), (r, c)), shape=(self.n_dofs, self.n_dofs))
