"""3-D tissue: P1 tetrahedral FEM, linear elastic and compressible neo-Hookean, with a
state that can be snapshotted and restored (the 3-D counterpart of :mod:`.linear` and
:mod:`.hyperelastic`).

Kinematics per tetrahedron (constant in the element): ``F = I + Σ_a u_a ⊗ ∇N_a``,
``J = det F``. Laws, with ``(λ, μ)`` the three-dimensional Lamé constants of the
:class:`~riskplan.deformable.material.Material` (``Material.lam3d``, ``Material.mu``; its
``plane`` field is a 2-D reduction and does not apply here):

* linear:  σ = λ tr(ε) I + 2 μ ε,  ε = sym ∇u;  stiffness ``K = λ K_λ + μ K_μ`` (the
  parts are assembled once per mesh, so a material draw costs one factorisation);
* neo-Hookean (compressible; the energy split used throughout):

      W(F) = μ/2 (I₁ − 3 − 2 ln J) + λ/2 (ln J)²,        I₁ = tr(FᵀF),
      P = ∂W/∂F = μ (F − F⁻ᵀ) + λ ln J F⁻ᵀ,
      ∂P_iJ/∂F_kL = μ δ_ik δ_JL + λ F⁻¹_Ji F⁻¹_Lk + (μ − λ ln J) F⁻¹_Li F⁻¹_Jk,

  which linearises at ``F = I`` to the linear law above.

Equilibrium (total Lagrangian): ``r(u) = f_int(u) − f_ext = 0`` at the free DOFs,
``f_int,a = Σ_e V_e P_e ∇N_a``. The element stiffness of both laws is
``K_{ai,bk} = V_e [μ δ_ik ∇N_a·∇N_b + λ h_ai h_bk + c h_bi h_ak]`` with ``h_a = F⁻ᵀ ∇N_a``
and ``c = μ − λ ln J`` (linear: ``F = I``, ``c = μ``). DOFs are interleaved,
``[u_x0, u_y0, u_z0, u_x1, ...]`` (scikit-fem's ``ElementVector(ElementTetP1())`` order),
so ``u.reshape(N, 3)`` is the nodal displacement. Linear systems: the reduced stiffness is
ordered by reverse Cuthill-McKee once per mesh and support set, and factorised as a banded
Cholesky matrix (sparse LU when the tangent is not positive definite).

Newton's method for the neo-Hookean law: full Newton with the consistent tangent, a
backtracking line search on the potential ``Π(u) = Σ_e V_e W(F_e) − f·u`` that also
rejects steps inverting an element, load stepping with halving of failed increments;
failure raises :class:`~riskplan.errors.ConvergenceError` (never a silent ``u = 0``).
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_array
from riskplan.deformable.banded import BandedCholeskySolver
from riskplan.deformable.hyperelastic import SolveInfo
from riskplan.deformable.material import Material
from riskplan.deformable.material_points import Interpolator
from riskplan.deformable.tetmesh import TetMesh
from riskplan.errors import ConvergenceError, ElementInversionError, InvalidInputError
from riskplan.threads import one_blas_thread

logger = logging.getLogger(__name__)

LAWS3D = ("linear", "neo-hookean")

#: A point counts as inside an element when its smallest barycentric weight is >= -INSIDE_TOL.
INSIDE_TOL = 1e-10

#: Element centroids tried per point before the exhaustive search (nearest first).
LOCATE_CANDIDATES = 12

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
        from scipy.sparse.csgraph import reverse_cuthill_mckee

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
        perm = reverse_cuthill_mckee(pattern.tocsr(), symmetric_mode=True)
        pos = np.empty(nf, dtype=np.int64)
        pos[perm] = np.arange(nf)
        pr, pc = pos[r], pos[c]
        upper = pr <= pc
        bw = int(np.max(pc[upper] - pr[upper])) if np.any(upper) else 0
        self.band_perm = perm
        self.bandwidth = bw
        self._band_sel = np.flatnonzero(upper)
        self._band_slot = (bw + pr[upper] - pc[upper]) * nf + pc[upper]
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
    key = (tets.shape, tets.tobytes(), free_dofs.tobytes(), int(n_dofs))
    p = _PATTERNS.get(key)
    if p is None:
        p = _PATTERNS[key] = TetPattern(tets, free_dofs, n_dofs)
        if len(_PATTERNS) > _PATTERN_CACHE:
            _PATTERNS.popitem(last=False)
    else:
        _PATTERNS.move_to_end(key)
    return p


def _norm(x: np.ndarray) -> float:
    """Euclidean norm without overflow for finite entries (scaled by the largest first)."""
    m = float(np.max(np.abs(x), initial=0.0))
    if m == 0.0 or not np.isfinite(m):
        return m
    return m * float(np.linalg.norm(x / m))


# --------------------------------------------------------------------------------------
# point location


def find_points(mesh: TetMesh, points: np.ndarray, k: int = LOCATE_CANDIDATES):
    """Containing element ``(P,)`` and barycentric weights ``(P, 4)`` of ``points (P, 3)``;
    element ``-1`` (weights of the best candidate) for points outside the mesh.

    The ``k`` elements with the nearest centroids (a k-d tree) are tried first; points not
    inside any of them are searched exhaustively, so the result does not depend on ``k``.
    Picks the element whose smallest barycentric weight is largest.
    """
    from scipy.spatial import cKDTree

    maps = mesh.barycentric_maps
    P = len(points)
    elem = np.full(P, -1, dtype=np.int64)
    lam = np.zeros((P, 4))
    if P == 0:
        return elem, lam
    tree = mesh.__dict__.get("_centroid_tree")
    if tree is None:
        tree = cKDTree(mesh.centroids)
        object.__setattr__(mesh, "_centroid_tree", tree)
    k = min(k, mesh.n_elements)
    _, cand = tree.query(points, k=k)
    cand = np.asarray(cand).reshape(P, k)
    b = np.einsum("pkij,pj->pki", maps[cand][:, :, :, :3], points) + maps[cand][:, :, :, 3]
    worst = b.min(axis=2)
    j = worst.argmax(axis=1)
    rows = np.arange(P)
    ok = worst[rows, j] >= -INSIDE_TOL
    elem[ok] = cand[rows[ok], j[ok]]
    lam[:] = b[rows, j]
    todo = np.flatnonzero(~ok)
    for s in range(0, len(todo), 64):
        idx = todo[s : s + 64]
        bb = np.einsum("tij,pj->pti", maps[:, :, :3], points[idx]) + maps[None, :, :, 3]
        w = bb.min(axis=2)
        e = w.argmax(axis=1)
        r = np.arange(len(idx))
        inside = w[r, e] >= -INSIDE_TOL
        elem[idx] = np.where(inside, e, -1)
        lam[idx] = bb[r, e]
    return elem, lam


def locate3d(mesh: TetMesh, points, name: str = "points") -> Interpolator:
    """An :class:`~riskplan.deformable.material_points.Interpolator` for material points ``(P, 3)``
    (or one ``(3,)``) of ``mesh``; raises :class:`InvalidInputError` naming the set
    (``name``: "target", "obstacle 2", ...) and the points outside the tissue."""
    pts = as_array(points, name, last_dim=3)
    if pts.ndim > 2:
        raise InvalidInputError(f"{name}: expected shape (P, 3) or (3,), got {pts.shape}")
    pts = np.ascontiguousarray(pts.reshape(-1, 3))
    elem, lam = find_points(mesh, pts)
    outside = np.flatnonzero(elem < 0)
    if outside.size:
        raise InvalidInputError(
            f"{name}: {outside.size} point(s) lie outside the tissue, e.g. index "
            f"{outside[:5].tolist()} at {pts[outside[:3]].tolist()}"
        )
    idx = mesh.tets[elem]
    for a in (pts, elem, lam, idx):
        a.setflags(write=False)
    return Interpolator(
        points=pts, elements=elem, node_index=idx, weights=lam, n_nodes=mesh.n_nodes
    )


def sphere_points(center, radius: float, n_points: int = 64) -> np.ndarray:
    """Material points ``(n_points + 1, 3)`` of a spherical region (an embedded obstacle or
    target): its centre and ``n_points`` points on its surface (Fibonacci lattice, nearly
    uniform). Locate them with :meth:`TetTissue.interpolator`; their deformed positions
    follow the tissue."""
    c = as_array(center, "center", shape=(3,))
    r = float(radius)
    if not (np.isfinite(r) and r > 0):
        raise InvalidInputError(f"radius: expected a finite radius > 0, got {radius!r}")
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)) or n_points < 4:
        raise InvalidInputError(f"n_points: expected an int >= 4, got {n_points!r}")
    k = np.arange(n_points) + 0.5
    z = 1.0 - 2.0 * k / n_points
    phi = np.pi * (1.0 + 5.0**0.5) * k
    rho = np.sqrt(1.0 - z * z)
    surf = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    return np.vstack([c, c + r * surf])


# --------------------------------------------------------------------------------------
# state and tissue


@dataclass(frozen=True, eq=False)
class TissueState3D:
    """What :meth:`TetTissue.snapshot` saves: the displacement ``(N, 3)`` and the nodal
    load ``(N, 3)`` it balances (read-only copies), and the mesh size it belongs to."""

    displacement: np.ndarray
    load: np.ndarray
    n_nodes: int

    def identical(self, other: TissueState3D) -> bool:
        """Bit-for-bit equality (the snapshot/restore contract)."""
        return (
            isinstance(other, TissueState3D)
            and self.n_nodes == other.n_nodes
            and self.displacement.tobytes() == other.displacement.tobytes()
            and self.load.tobytes() == other.load.tobytes()
        )


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64, copy=True, order="C")
    a.setflags(write=False)
    return a


class TetTissue:
    """A 3-D elastic body on a :class:`~riskplan.deformable.tetmesh.TetMesh` with the
    nodes ``fixed_nodes`` held, and a current state (displacement and the load it balances).

    Parameters
    ----------
    mesh: :class:`TetMesh`
    material: :class:`Material` (``E``, ``nu``; 3-D Lamé constants are used)
    fixed_nodes: ``(F,)`` node indices held (all three components) at zero displacement (or
        at ``fixed_values`` given to a solve); at least three nodes not on one line unless
        ``fixed_dofs`` is given.
    fixed_dofs: ``(D,)`` further held DOFs, flat interleaved indices ``3 a + i`` (rollers,
        symmetry planes). Attributes ``fixed_dofs`` / ``free_dofs`` hold all of them.
    law: ``"linear"`` or ``"neo-hookean"``.
    rtol, atol, max_iter: Newton's tolerance ``‖r_free‖ ≤ rtol · ‖f‖ + atol`` and
        iteration limit (neo-Hookean).

    The linear law factorises its stiffness once (at construction) and re-uses it for
    every solve; :meth:`with_material` re-uses the assembly for a material draw. Solves
    update the current state; :meth:`snapshot` / :meth:`restore` save and bring it back
    (bit for bit). The neo-Hookean solve starts from the current state (warm start).
    """

    def __init__(
        self,
        mesh: TetMesh,
        material: Material,
        fixed_nodes=None,
        *,
        fixed_dofs=None,
        law: str = "linear",
        rtol: float = 1e-9,
        atol: float = 1e-12,
        max_iter: int = 25,
        _parts=None,
    ):
        if not isinstance(mesh, TetMesh):
            raise InvalidInputError(f"mesh: expected a TetMesh, got {type(mesh).__name__}")
        if not isinstance(material, Material):
            raise InvalidInputError(f"material: expected a Material, got {type(material).__name__}")
        if law not in LAWS3D:
            raise InvalidInputError(f"law: expected one of {LAWS3D}, got {law!r}")
        self.rtol, self.atol, self.max_iter = float(rtol), float(atol), int(max_iter)
        if not (0.0 < self.rtol < 1.0) or not (0.0 <= self.atol < np.inf) or self.max_iter < 1:
            raise InvalidInputError(
                f"rtol, atol, max_iter: expected 0 < rtol < 1, finite atol >= 0, max_iter >= 1; "
                f"got {rtol!r}, {atol!r}, {max_iter!r}"
            )
        self.mesh = mesh
        self.material = material
        self.law = law
        n = 3 * mesh.n_nodes
        self._n = n
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
        self.fixed_nodes = fixed
        fixed.setflags(write=False)
        mask = np.ones(n, dtype=bool)
        mask[(3 * fixed[:, None] + np.arange(3)).ravel()] = False
        mask[extra] = False
        self.fixed_dofs, self.free_dofs = np.flatnonzero(~mask), np.flatnonzero(mask)
        if self.free_dofs.size == 0:
            raise InvalidInputError("fixed_nodes, fixed_dofs: every DOF is fixed; nothing to solve")
        self._fixed_dofs_arg = extra
        self._pattern = _pattern(mesh.tets, self.free_dofs, n)
        self._lam, self._mu = material.lam3d, material.mu
        self._G = mesh.shape_gradients
        self._V = mesh.volumes
        self._tets_flat = np.ascontiguousarray(mesh.tets.ravel())
        self._u = np.zeros(n)
        self._f = np.zeros(n)
        self._parts = _parts
        self._linear_solver = None
        if law == "linear":
            self._factorise_linear()

    # ---- construction ------------------------------------------------------------------
    def _linear_parts(self):
        """``(K_λ, K_μ)`` element matrices ``(T·144,)`` (flat) of the linear stiffness with
        ``(λ, μ) = (1, 0)`` and ``(0, 1)``."""
        if self._parts is None:
            self._parts = (
                element_stiffness(self._G, self._V, 1.0, 0.0).reshape(-1),
                element_stiffness(self._G, self._V, 0.0, 1.0).reshape(-1),
            )
        return self._parts

    @one_blas_thread
    def _factorise_linear(self) -> None:
        Kl, Km = self._linear_parts()
        self._linear_solver = self._factor(self._lam * Kl + self._mu * Km, linear=True)

    def _factor(self, Ke_flat: np.ndarray, linear: bool = False):
        """Solver ``r -> K_ff⁻¹ r`` of the reduced matrix: banded Cholesky in RCM order,
        sparse LU when it is not positive definite."""
        import scipy.linalg

        try:
            cb = scipy.linalg.cholesky_banded(
                self._pattern.banded(Ke_flat), lower=False, check_finite=False
            )
            return BandedCholeskySolver(cb, self._pattern.band_perm)
        except np.linalg.LinAlgError:
            from scipy.sparse.linalg import splu

            try:
                return splu(self._pattern.csc(Ke_flat)).solve
            except RuntimeError as exc:
                if linear:
                    raise InvalidInputError(
                        "fixed_nodes: the stiffness is singular (some part of the mesh is not "
                        "held by the fixed nodes)"
                    ) from exc
                raise ConvergenceError(f"Newton: singular tangent ({exc})") from exc

    def with_material(self, material: Material) -> TetTissue:
        """The same mesh, supports and law with another material (a material draw): re-uses
        the sparsity layout and, for the linear law, the assembled parts; state at rest."""
        return TetTissue(
            self.mesh,
            material,
            self.fixed_nodes,
            fixed_dofs=self._fixed_dofs_arg,
            law=self.law,
            rtol=self.rtol,
            atol=self.atol,
            max_iter=self.max_iter,
            _parts=self._parts,
        )

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_linear_solver"] = None
        state["_pattern"] = None
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._pattern = _pattern(self.mesh.tets, self.free_dofs, self._n)
        if self.law == "linear":
            self._factorise_linear()

    @property
    def n_dofs(self) -> int:
        return self._n

    # ---- state --------------------------------------------------------------------------
    @property
    def displacement(self) -> np.ndarray:
        """Current displacement ``(N, 3)`` (a read-only view)."""
        v = self._u.reshape(-1, 3).view()
        v.setflags(write=False)
        return v

    def snapshot(self) -> TissueState3D:
        """The current state (read-only copies)."""
        return TissueState3D(
            displacement=_frozen(self._u.reshape(-1, 3)),
            load=_frozen(self._f.reshape(-1, 3)),
            n_nodes=self.mesh.n_nodes,
        )

    def restore(self, state: TissueState3D) -> None:
        """Make ``state`` (from :meth:`snapshot` of a tissue on the same mesh) current."""
        if not isinstance(state, TissueState3D):
            raise InvalidInputError(f"state: expected a TissueState3D, got {type(state).__name__}")
        if state.n_nodes != self.mesh.n_nodes:
            raise InvalidInputError(
                f"state: belongs to a mesh of {state.n_nodes} nodes, this one has {self.mesh.n_nodes}"
            )
        self._u = np.array(state.displacement, dtype=np.float64).reshape(-1)
        self._f = np.array(state.load, dtype=np.float64).reshape(-1)

    def reset(self) -> None:
        """Back to the undeformed, unloaded state."""
        self._u = np.zeros(self._n)
        self._f = np.zeros(self._n)

    # ---- material points ----------------------------------------------------------------
    def locate(self, points):
        """``(elements (P,), weights (P, 4))`` of reference points ``(P, 3)``: containing
        element (``-1`` outside the tissue) and barycentric weights."""
        pts = np.ascontiguousarray(as_array(points, "points", last_dim=3).reshape(-1, 3))
        return find_points(self.mesh, pts)

    def contains(self, points) -> np.ndarray:
        """``(P,)`` bool: which reference points lie in the tissue."""
        return self.locate(points)[0] >= 0

    def interpolator(self, points, name: str = "points") -> Interpolator:
        """Barycentric interpolation at material points ``(P, 3)`` (an embedded target or
        obstacle: :func:`sphere_points`); raises :class:`InvalidInputError` naming ``name``
        for points outside the tissue."""
        return locate3d(self.mesh, points, name)

    def displacement_at(self, points, u=None) -> np.ndarray:
        """Displacement ``(P, 3)`` of material points ``(P, 3)`` (P1 interpolant
        ``Σ_a λ_a u_a``) in the current state, or in ``u (N, 3)``."""
        return self.interpolator(points).interpolate(self._field(u))

    def positions(self, points, u=None) -> np.ndarray:
        """Deformed positions ``X + u(X)`` ``(P, 3)`` of material points ``X (P, 3)``."""
        return self.interpolator(points).positions(self._field(u))

    def deformation_gradient_at(self, points, u=None) -> np.ndarray:
        """``F = I + ∇_X u`` ``(P, 3, 3)`` at material points ``(P, 3)`` (constant in each
        element; a point on a shared face takes one of its elements)."""
        ip = self.interpolator(points)
        u3 = self._field(u)
        e = ip.elements
        return deformation_gradients(u3[self.mesh.tets[e]], self._G[e])

    def point_forces(self, points, forces) -> np.ndarray:
        """Consistent nodal forces ``(N, 3)`` of point forces ``forces (P, 3)`` at material
        points ``(P, 3)``: ``f_a = λ_a(X_p) F_p`` over the containing element's nodes."""
        ip = self.interpolator(points)
        f = as_array(forces, "forces", shape=(ip.n_points, 3))
        return ip.spread(f)

    def _field(self, u) -> np.ndarray:
        if u is None:
            return self._u.reshape(-1, 3)
        return as_array(u, "u", shape=(self.mesh.n_nodes, 3))

    # ---- evaluations --------------------------------------------------------------------
    def _F(self, u_flat: np.ndarray) -> np.ndarray:
        return deformation_gradients(u_flat.reshape(-1, 3)[self.mesh.tets], self._G)

    def _internal(self, u_flat: np.ndarray):
        """``(energy, f_int (3N,), J, F⁻¹, ln J)``; ``energy`` is ``None`` if an element
        inverted (neo-Hookean)."""
        if self.law == "linear":
            Kl, Km = self._linear_parts()
            ue = u_flat[self._pattern.element_dofs]  # (T, 12)
            Ke = (self._lam * Kl + self._mu * Km).reshape(-1, 12, 12)
            fe = np.einsum("tij,tj->ti", Ke, ue)
            fint = np.bincount(self._pattern.element_dofs.ravel(), fe.ravel(), minlength=self._n)
            return 0.5 * float(u_flat @ fint), fint, None, None, None
        F = self._F(u_flat)
        W, P, J, Finv = neohookean_stress(F, self._lam, self._mu)
        if W is None:
            return None, None, J, None, None
        fe = np.matmul(self._G, np.swapaxes(P, 1, 2)) * self._V[:, None, None]  # (T, 4, 3)
        fint = np.bincount(self._pattern.element_dofs.ravel(), fe.ravel(), minlength=self._n)
        return float(self._V @ W), fint, J, Finv, np.log(J)

    def energy(self, u=None) -> float:
        """Stored energy ``Σ_e V_e W(F_e)`` (linear: ``½ uᵀ K u``) of ``u (N, 3)`` or the
        current state; raises :class:`ElementInversionError` for an inverted element."""
        e, _, J, _, _ = self._internal(self._field(u).reshape(-1).copy())
        if e is None:
            self._raise_inverted(J)
        return e

    def internal_forces(self, u=None) -> np.ndarray:
        """Internal nodal forces ``f_int (N, 3)`` (all nodes, reactions included)."""
        e, fint, J, _, _ = self._internal(self._field(u).reshape(-1).copy())
        if e is None:
            self._raise_inverted(J)
        return fint.reshape(-1, 3)

    def residual(self, u, nodal_forces) -> np.ndarray:
        """``f_int(u) − f`` ``(N, 3)``, zero at the fixed nodes."""
        f = as_array(nodal_forces, "nodal_forces", shape=(self.mesh.n_nodes, 3)).reshape(-1)
        r = self.internal_forces(u).reshape(-1) - f
        r[self.fixed_dofs] = 0.0
        return r.reshape(-1, 3)

    def reactions(self, u=None) -> np.ndarray:
        """Support reactions ``(F, 3)``: ``f_int`` at the fixed nodes."""
        return self.internal_forces(u)[self.fixed_nodes]

    def tangent(self, u=None, *, full: bool = False):
        """Tangent stiffness ``∂f_int/∂u``: reduced CSC ``(n_free, n_free)`` or, with
        ``full=True``, CSR ``(3N, 3N)``."""
        Ke = self._tangent_elements(self._field(u).reshape(-1).copy())
        return self._pattern.full_csr(Ke.reshape(-1, 12, 12)) if full else self._pattern.csc(Ke)

    def _tangent_elements(self, u_flat: np.ndarray) -> np.ndarray:
        if self.law == "linear":
            Kl, Km = self._linear_parts()
            return self._lam * Kl + self._mu * Km
        F = self._F(u_flat)
        J = np.linalg.det(F)
        if np.any(J <= 0):
            self._raise_inverted(J)
        return element_stiffness(
            self._G, self._V, self._lam, self._mu, np.linalg.inv(F), np.log(J)
        ).reshape(-1)

    def _raise_inverted(self, J: np.ndarray, context: str = ""):
        bad = np.flatnonzero(J <= 0.0)
        raise ElementInversionError(
            f"{bad.size} element(s) inverted (det F <= 0){context}: elements {bad[:10].tolist()}, "
            f"min det F = {float(J.min()):.3g}",
            elements=bad,
            min_jacobian=float(J.min()),
        )

    # ---- solves -------------------------------------------------------------------------
    def solve_linear_free(self, f_free: np.ndarray) -> np.ndarray:
        """``K_ff⁻¹ f_free`` with the cached factorisation (linear law; no validation)."""
        return self._linear_solver(f_free)

    def solve(self, nodal_forces, *, fixed_values=None, load_steps: int = 1) -> np.ndarray:
        """Equilibrium displacement ``(N, 3)`` under the nodal forces ``(N, 3)`` (entries at
        fixed nodes are ignored); becomes the current state. See :meth:`solve_with_info`."""
        return self.solve_with_info(nodal_forces, fixed_values=fixed_values, load_steps=load_steps)[
            0
        ]

    @one_blas_thread
    def solve_with_info(self, nodal_forces, *, fixed_values=None, load_steps: int = 1):
        """Equilibrium displacement ``(N, 3)`` and :class:`~riskplan.deformable.SolveInfo`.

        ``fixed_values``: prescribed displacements of the fixed DOFs in ``fixed_dofs``
        order (sorted flat DOF index; ``(F, 3)`` in sorted node order when only
        ``fixed_nodes`` are given), default zero. Linear law: ``u_f = K_ff⁻¹ (f_f − K_fc ū)`` with the cached
        factorisation. Neo-Hookean: Newton from the current state, the load (and the
        prescribed values) ramped from the current ones in ``load_steps`` increments, a
        failed increment halved up to 8 times; raises :class:`ConvergenceError` or
        :class:`ElementInversionError` (the state is then unchanged).
        """
        f = as_array(nodal_forces, "nodal_forces", shape=(self.mesh.n_nodes, 3)).reshape(-1).copy()
        f[self.fixed_dofs] = 0.0
        if isinstance(load_steps, bool) or not isinstance(load_steps, (int, np.integer)):
            raise InvalidInputError(f"load_steps: expected an int >= 1, got {load_steps!r}")
        if load_steps < 1:
            raise InvalidInputError(f"load_steps: expected an int >= 1, got {load_steps!r}")
        if fixed_values is None:
            ub = np.zeros(len(self.fixed_dofs))
        else:
            ub = as_array(fixed_values, "fixed_values").reshape(-1)
            if ub.size != len(self.fixed_dofs):
                raise InvalidInputError(
                    f"fixed_values: expected {len(self.fixed_dofs)} values (one per fixed DOF: "
                    f"(F, 3) for fixed_nodes alone), got shape {np.shape(fixed_values)}"
                )
        if self.law == "linear":
            u = np.zeros(self._n)
            u[self.fixed_dofs] = ub
            rhs = f[self.free_dofs]
            if np.any(ub):
                Kfull = self.tangent(full=True)
                rhs = rhs - Kfull[self.free_dofs][:, self.fixed_dofs] @ ub
            u[self.free_dofs] = self._linear_solver(rhs)
            if not np.all(np.isfinite(u)):
                raise ConvergenceError(
                    "linear solve: the displacement overflows float64 (loads too large)",
                    residual=float("inf"),
                    iterations=0,
                )
            self._u, self._f = u, f
            return u.reshape(-1, 3).copy(), SolveInfo(1, 1, 0.0, 1.0)
        return self._solve_nonlinear(f, ub, int(load_steps))

    def _solve_nonlinear(self, f: np.ndarray, ub: np.ndarray, load_steps: int, max_halvings=8):
        u = self._u.copy()
        f0 = self._f.copy()
        ub0 = u[self.fixed_dofs].copy()
        moving = bool(np.any(ub != ub0))
        fscale = max(_norm(f[self.free_dofs]), _norm(f0[self.free_dofs]))
        if not np.isfinite(fscale):
            raise InvalidInputError("nodal_forces: the load's norm overflows float64")
        if moving:  # forces of the order the prescribed motion produces
            probe = np.zeros(self._n)
            probe[self.fixed_dofs] = ub - ub0
            Kfull = self.tangent(u.reshape(-1, 3), full=True)
            fscale = max(fscale, _norm((Kfull @ probe)[self.free_dofs]))
        if fscale == 0.0:
            fscale = 1.0
        s, ds = 0.0, 1.0 / load_steps
        iters = steps = halvings = 0
        rn = 0.0
        J = None
        while s < 1.0 - 1e-15:
            s1 = min(1.0, s + ds)
            fs = f0 + s1 * (f - f0) if s1 < 1.0 else f
            try:
                start = u
                if moving:
                    target = ub0 + s1 * (ub - ub0) if s1 < 1.0 else ub
                    start = self._predictor(u, target - u[self.fixed_dofs])
                u_new, it, rn, J = self._newton(start, fs, fscale)
            except (ConvergenceError, ElementInversionError) as exc:
                if halvings >= max_halvings:
                    raise
                halvings += 1
                ds *= 0.5
                logger.debug("load step %.3g -> %.3g failed (%s); halving", s, s1, exc)
                continue
            iters += it
            steps += 1
            u, s = u_new, s1
            if it <= 4:
                ds = min(2.0 * ds, 1.0 / load_steps)
        if J is None:
            _, _, J, _, _ = self._internal(u)
        self._u, self._f = u, f
        return u.reshape(-1, 3).copy(), SolveInfo(iters, steps, rn, float(np.min(J)))

    def _predictor(self, u: np.ndarray, dub: np.ndarray) -> np.ndarray:
        """Fixed DOFs moved by ``dub``, free ones by the linearised response
        ``−K_ff⁻¹ K_fc dub`` (so a prescribed motion does not crush the elements next to
        the supports)."""
        Ke = self._tangent_elements(u)
        Kfull = self._pattern.full_csr(Ke.reshape(-1, 12, 12))
        rhs = Kfull[self.free_dofs][:, self.fixed_dofs] @ dub
        out = u.copy()
        out[self.fixed_dofs] += dub
        out[self.free_dofs] -= self._factor(Ke)(rhs)
        return out

    def _newton(self, u: np.ndarray, f: np.ndarray, fscale: float):
        """Newton with backtracking on Π from ``u`` for the load ``f`` (flat)."""
        free = self.free_dofs
        energy, fint, J, Finv, lnJ = self._internal(u)
        if energy is None:
            self._raise_inverted(J, " at the start of a load step")
        tol = self.rtol * fscale + self.atol
        f_free = f[free]
        r = fint[free] - f_free
        rn = _norm(r)
        for it in range(self.max_iter + 1):
            if not np.isfinite(rn):
                raise ConvergenceError(
                    f"Newton: non-finite residual ({rn}) after {it} iteration(s)",
                    residual=rn,
                    iterations=it,
                )
            if rn <= tol:
                return u, it, rn, J
            if it == self.max_iter:
                break
            Ke = element_stiffness(self._G, self._V, self._lam, self._mu, Finv, lnJ).reshape(-1)
            try:
                du = -self._factor(Ke)(r)
            except ConvergenceError as exc:
                exc.residual, exc.iterations = rn, it
                raise
            pi0 = energy - float(f @ u)
            slope = float(r @ du)
            if not slope < 0.0:  # indefinite tangent: steepest descent
                du = -r
                slope = -rn * rn
            alpha = 1.0
            J_bad = None
            for _ in range(40):
                trial = u.copy()
                trial[free] += alpha * du
                e1, fint1, J1, Finv1, lnJ1 = self._internal(trial)
                if e1 is None:
                    J_bad = J1
                    alpha *= 0.5
                    continue
                r1 = fint1[free] - f_free
                rn1 = _norm(r1)
                if e1 - float(f @ trial) <= pi0 + 1e-4 * alpha * slope or rn1 < 0.5 * rn:
                    break
                alpha *= 0.5
            else:
                if J_bad is not None:
                    self._raise_inverted(J_bad, " in every line-search trial")
                raise ConvergenceError(
                    f"Newton line search failed (residual {rn:.3g})", residual=rn, iterations=it
                )
            u, energy, fint, J, Finv, lnJ = trial, e1, fint1, J1, Finv1, lnJ1
            r, rn = r1, rn1
        raise ConvergenceError(
            f"Newton did not converge in {self.max_iter} iterations (residual {rn:.3g}, "
            f"tolerance {tol:.3g})",
            residual=rn,
            iterations=self.max_iter,
        )

    def __repr__(self) -> str:
        return (
            f"TetTissue(law={self.law!r}, E={self.material.E:g}, nu={self.material.nu:g}, "
            f"n_elements={self.mesh.n_elements}, fixed_nodes={self.fixed_nodes.size})"
        )
