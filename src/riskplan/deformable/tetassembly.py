"""Element kinematics, laws and sparse assembly of P1 tetrahedra (the pure parts of
:mod:`riskplan.deformable.tissue3d`): deformation gradients, the compressible neo-Hookean
stress, element stiffness matrices of both laws, the sparsity layout (``TetPattern``) that
the banded Cholesky factorisation fills, and the held and free DOFs of the supports
(``support_dofs``, checked to hold every rigid motion).

Element matrices are in local DOF order ``(a, i)`` (node ``a`` of the tetrahedron,
component ``i``); DOFs are interleaved ``[u_x0, u_y0, u_z0, u_x1, …]``.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from riskplan.deformable.banded import band_layout, cached_layout
from riskplan.errors import InvalidInputError

# sparsity layouts by (tets, free DOFs): tissues of one mesh with different materials share one
_PATTERNS: OrderedDict = OrderedDict()
_PATTERN_CACHE = 8


# --------------------------------------------------------------------------------------
# pure element functions


def deformation_gradients(u_elem: np.ndarray, G: np.ndarray) -> np.ndarray:
    """``F = I + Σ_a u_a ⊗ ∇N_a`` ``(T, 3, 3)`` from ``u_elem (T, 4, 3)``, ``G (T, 4, 3)``."""
    F = np.einsum("tai,taj->tij", u_elem, G)
    F[:, 0, 0] += 1.0
    F[:, 1, 1] += 1.0
    F[:, 2, 2] += 1.0
    return F


def neohookean_stress(F: np.ndarray, lam: float, mu: float):
    """``(W (T,), P (T, 3, 3), J (T,), F⁻¹ (T, 3, 3))`` of the compressible neo-Hookean law
    (module docstring); ``W`` is ``None`` when some ``J ≤ 0``."""
    J = np.linalg.det(F)
    if np.any(J <= 0.0):
        return None, None, J, None
    Finv = np.linalg.inv(F)
    FinvT = np.swapaxes(Finv, 1, 2)
    lnJ = np.log(J)
    I1 = np.einsum("tij,tij->t", F, F)
    W = 0.5 * mu * (I1 - 3.0 - 2.0 * lnJ) + 0.5 * lam * lnJ**2
    P = mu * (F - FinvT) + (lam * lnJ)[:, None, None] * FinvT
    return W, P, J, Finv


def element_stiffness(
    G: np.ndarray,
    volumes: np.ndarray,
    lam: float,
    mu: float,
    Finv: np.ndarray | None = None,
    lnJ: np.ndarray | None = None,
) -> np.ndarray:
    """Element matrices ``(T, 12, 12)`` in local DOF order ``(a, i)``:

        K_{ai,bk} = V [μ δ_ik ∇N_a·∇N_b + λ h_ai h_bk + c h_bi h_ak],   h_a = F⁻ᵀ ∇N_a,

    the linear stiffness for ``Finv=None`` (``h = ∇N``, ``c = μ``), else the neo-Hookean
    tangent at ``F`` (``c = μ − λ ln J``; ``F⁻¹ (T, 3, 3)`` and ``ln J (T,)`` given).
    """
    T = len(volumes)
    h = G.reshape(T, 12) if Finv is None else np.matmul(G, Finv).reshape(T, 12)
    O = h[:, :, None] * h[:, None, :]  # (T, (a,i), (b,k)): h_ai h_bk
    swapped = O.reshape(T, 4, 3, 4, 3).transpose(0, 3, 2, 1, 4).reshape(T, 12, 12)  # h_bi h_ak
    c = np.full(T, float(mu)) if lnJ is None else mu - lam * lnJ
    K = lam * O + c[:, None, None] * swapped
    GG = mu * np.matmul(G, np.swapaxes(G, 1, 2))  # (T, a, b)
    for i in range(3):
        K[:, i::3, i::3] += GG
    return K * volumes[:, None, None]


def linear_stiffness_parts(G: np.ndarray, volumes: np.ndarray):
    """``(K_λ, K_μ)``: flat element matrices ``(T·144,)`` of the linear stiffness for
    ``(λ, μ) = (1, 0)`` and ``(0, 1)`` (``K = λ K_λ + μ K_μ``; :func:`element_stiffness` with
    ``F = I``), from one outer product ``∇N_ai ∇N_bk``."""
    T = len(volumes)
    h = G.reshape(T, 12)
    O = h[:, :, None] * h[:, None, :]  # ∇N_ai ∇N_bk
    Km = O.reshape(T, 4, 3, 4, 3).transpose(0, 3, 2, 1, 4).reshape(T, 12, 12)  # ∇N_bi ∇N_ak
    GG = np.matmul(G, np.swapaxes(G, 1, 2))
    for i in range(3):
        Km[:, i::3, i::3] += GG
    v = volumes[:, None, None]
    return (O * v).reshape(-1), (Km * v).reshape(-1)


class TetPattern:
    """Index maps from the ``T·144`` element-matrix entries to the CSC matrix over all DOFs,
    its reduced part over ``free_dofs``, and the upper band of the reduced matrix in reverse
    Cuthill-McKee order (the layout of ``scipy.linalg.cholesky_banded``); built once per
    mesh and support set from the node adjacency (``T·16`` node pairs, each a 3×3 block), so
    an assembly is one ``bincount`` and two gathers.

    Attributes: ``element_dofs (T, 12)``, ``band_perm (n_free,)``, ``bandwidth``.
    """

    def __init__(self, tets: np.ndarray, free_dofs: np.ndarray, n_dofs: int):
        from scipy import sparse

        T = len(tets)
        N = n_dofs // 3
        self.element_dofs = (3 * tets[:, :, None] + np.arange(3)[None, None, :]).reshape(-1, 12)
        self.n_dofs = n_dofs
        # node pairs (a, b) of every element, keyed column-major: b (column) then a (row)
        na = np.repeat(tets, 4, axis=1).ravel()  # (T·16,) row node of (a, b)
        nb = np.tile(tets, (1, 4)).ravel()  # column node
        uniq, pair = np.unique(nb * N + na, return_inverse=True)
        col_node = uniq // N
        ptr = np.searchsorted(col_node, np.arange(N + 1))  # node-pair pointer per column node
        m = np.diff(ptr)  # pairs per column node
        # full CSC slot of entry (t, a, i, b, k): 9 ptr[b] + 3 m_b k + 3 j + i, j = pair - ptr[b]
        pair = pair.reshape(T, 4, 4)
        nbn = tets[:, None, :]  # (T, 1, 4): node of b
        base = 9 * ptr[nbn] + 3 * (pair - ptr[nbn])  # (T, 4a, 4b)
        i = np.arange(3)[None, None, :, None, None]
        k = np.arange(3)[None, None, None, None, :]
        slot = base[:, :, None, :, None] + i + 3 * m[nbn][:, :, None, :, None] * k
        self._slot = slot.reshape(-1)  # order (t, a, i, b, k) = element-matrix order
        nnz = 9 * len(uniq)
        self._nnz_full = nnz
        # row and column DOF of every full slot
        rows = np.empty(nnz, dtype=np.int64)
        cols = np.empty(nnz, dtype=np.int64)
        rows[self._slot] = self.element_dofs[:, :, None].repeat(12, 2).reshape(-1)
        cols[self._slot] = self.element_dofs[:, None, :].repeat(12, 1).reshape(-1)
        self._full_indices = rows.astype(np.int32)
        self._full_indptr = np.concatenate([[0], np.cumsum(np.repeat(3 * m, 3))]).astype(np.int32)
        nf = len(free_dofs)
        red = np.full(n_dofs, -1, dtype=np.int64)
        red[free_dofs] = np.arange(nf)
        r, c = red[rows], red[cols]
        keep = (r >= 0) & (c >= 0)
        self._keep = np.flatnonzero(keep)
        r, c = r[keep], c[keep]
        self._shape = (nf, nf)
        self._indices = r.astype(np.int32)
        self._indptr = np.searchsorted(c, np.arange(nf + 1)).astype(np.int32)
        pattern = sparse.csc_matrix(
            (np.ones(len(r)), self._indices, self._indptr), shape=self._shape
        )
        self.band_perm, bw, upper, self._band_slot = band_layout(pattern, r, c, nf)
        self.bandwidth = bw
        self._band_sel = np.flatnonzero(upper)
        self._band_size = (bw + 1) * nf

    def _full_data(self, Ke_flat: np.ndarray) -> np.ndarray:
        return np.bincount(self._slot, Ke_flat, minlength=self._nnz_full)

    def csc(self, Ke_flat: np.ndarray):
        """Reduced ``(n_free, n_free)`` CSC matrix from element matrices ``(T·144,)``."""
        from scipy import sparse

        data = self._full_data(Ke_flat)[self._keep]
        return sparse.csc_matrix((data, self._indices, self._indptr), shape=self._shape)

    def banded(self, Ke_flat: np.ndarray) -> np.ndarray:
        """Upper band ``(bandwidth + 1, n_free)`` of the RCM-permuted reduced matrix."""
        ab = np.zeros(self._band_size)
        ab[self._band_slot] = self._full_data(Ke_flat)[self._keep][self._band_sel]
        return ab.reshape(self.bandwidth + 1, -1)

    def full_csr(self, Ke: np.ndarray):
        """The ``(3N, 3N)`` matrix over all DOFs (CSR) from element matrices ``(T, 12, 12)``."""
        from scipy import sparse

        data = self._full_data(np.ascontiguousarray(Ke).reshape(-1))
        return sparse.csc_matrix(
            (data, self._full_indices, self._full_indptr), shape=(self.n_dofs, self.n_dofs)
        ).tocsr()


def _pattern(tets: np.ndarray, free_dofs: np.ndarray, n_dofs: int) -> TetPattern:
    return cached_layout(_PATTERNS, TetPattern, tets, free_dofs, n_dofs, _PATTERN_CACHE)


def _norm(x: np.ndarray) -> float:
    """Euclidean norm without overflow for finite entries (scaled by the largest first)."""
    m = float(np.max(np.abs(x), initial=0.0))
    if m == 0.0 or not np.isfinite(m):
        return m
    return m * float(np.linalg.norm(x / m))


def support_dofs(mesh, fixed_nodes, fixed_dofs):
    """The held and free DOFs of supports on a tetrahedral mesh, checked to hold every rigid
    motion (else the stiffness is singular whatever the law).

    Parameters
    ----------
    mesh : TetMesh
        The mesh.
    fixed_nodes : array_like of int or None
        Nodes held in all three components; at least three not on one line unless
        ``fixed_dofs`` is given.
    fixed_dofs : array_like of int or None
        Further held DOFs, flat interleaved indices ``3 a + i``.

    Returns
    -------
    fixed_nodes : numpy.ndarray
        Sorted unique held nodes (read-only).
    extra : numpy.ndarray
        Sorted unique further held DOFs.
    fixed : numpy.ndarray
        Every held DOF, sorted.
    free : numpy.ndarray
        The free DOFs, sorted.

    Raises
    ------
    InvalidInputError
        Indices out of range, every DOF held, or a rigid motion left free.
    """
    n = 3 * mesh.n_nodes
    fixed = np.unique(
        np.asarray([] if fixed_nodes is None else fixed_nodes, dtype=np.int64).reshape(-1)
    )
    if fixed.size and (fixed.min() < 0 or fixed.max() >= mesh.n_nodes):
        raise InvalidInputError(f"fixed_nodes: indices must lie in [0, {mesh.n_nodes - 1}]")
    extra = np.unique(
        np.asarray([] if fixed_dofs is None else fixed_dofs, dtype=np.int64).reshape(-1)
    )
    if extra.size and (extra.min() < 0 or extra.max() >= n):
        raise InvalidInputError(f"fixed_dofs: indices must lie in [0, {n - 1}]")
    if extra.size == 0 and (
        fixed.size < 3 or np.linalg.matrix_rank(mesh.nodes[fixed] - mesh.nodes[fixed[0]]) < 2
    ):
        raise InvalidInputError(
            "fixed_nodes: hold at least three nodes not on one line (else a rigid motion is free)"
        )
    fixed.setflags(write=False)
    mask = np.ones(n, dtype=bool)
    mask[(3 * fixed[:, None] + np.arange(3)).ravel()] = False
    mask[extra] = False
    fixed_all, free = np.flatnonzero(~mask), np.flatnonzero(mask)
    if free.size == 0:
        raise InvalidInputError("fixed_nodes, fixed_dofs: every DOF is fixed; nothing to solve")
    # the six rigid motions (3 translations, 3 infinitesimal rotations) must each move
    # some held DOF, else the stiffness is singular whatever the law
    Xc = mesh.nodes - mesh.nodes.mean(0)
    rigid = np.zeros((mesh.n_nodes, 3, 6))
    for k in range(3):
        rigid[:, k, k] = 1.0
    rigid[:, :, 3:] = np.cross(np.eye(3)[None, :, :], Xc[:, None, :]).transpose(0, 2, 1)
    R = rigid.reshape(n, 6)[fixed_all]
    if np.linalg.matrix_rank(R, tol=1e-9 * float(np.abs(R).max(initial=1.0))) < 6:
        raise InvalidInputError(
            "fixed_nodes, fixed_dofs: the supports leave a rigid motion free (hold "
            "at least three non-collinear nodes, or enough components)"
        )
    return fixed, extra, fixed_all, free
