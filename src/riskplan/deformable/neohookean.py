"""Geometrically nonlinear (hyperelastic) P1 FEM: compressible neo-Hookean and
St Venant-Kirchhoff (paper V-B: "a geometrically nonlinear FEM simulator to accurately
simulate the large deformations of the object").

Total Lagrangian form. With deformation gradient ``F = I + ∇_X u`` (constant per P1
element), ``J = det F``, ``I₁ = tr(FᵀF)``, the stored energies (per unit reference area)

* neo-Hookean (2-D, plane strain):  W = μ/2 (I₁ − 2 − 2 ln J) + λ/2 (ln J)²
  first Piola-Kirchhoff stress  P = μ (F − F⁻ᵀ) + λ ln J F⁻ᵀ
* St Venant-Kirchhoff:  E = ½(FᵀF − I),  W = μ E:E + λ/2 (tr E)²,  P = F (2 μ E + λ tr E I)

both linearise at ``F = I`` to ``σ = λ tr(ε) I + 2 μ ε``. We use ``(λ, μ) = Material.lame``:
for ``plane="strain"`` this is the exact plane-strain neo-Hookean model; for
``plane="stress"`` it is the 2-D model with the plane-stress λ₂ = Eν/(1−ν²), which equals
plane-stress linear elasticity at small strain (a thin-sheet model would need the
out-of-plane stretch as an extra unknown; we do not model it).

Equilibrium: ``r(u) = f_int(u) − f_ext = 0`` on free DOFs, with
``f_int,a = Σ_e A_e P_e ∇N_a`` and tangent ``K_{ai,bk} = Σ_e A_e ∂P_iJ/∂F_kL ∇N_aJ ∇N_bL``.
Newton's method with a backtracking line search on the total potential energy
``Π(u) = Σ_e A_e W(F_e) − f_ext·u``, that also rejects steps inverting an element
(``det F ≤ 0``), load stepping (adaptive halving) and warm starts.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_array
from riskplan.deformable.material import Material
from riskplan.deformable.mesh import TissueMesh
from riskplan.errors import ConvergenceError, ElementInversionError, InvalidInputError
from riskplan.threads import one_blas_thread

logger = logging.getLogger(__name__)

LAWS = ("neohookean", "svk")


def shape_gradients(mesh: TissueMesh) -> np.ndarray:
    """``(T, 3, 2)`` reference gradients ``∇_X N_a`` of the P1 shape functions (cached)."""
    G = mesh.__dict__.get("_shape_grads")
    if G is None:
        p = mesh.nodes[mesh.triangles]
        d1 = p[:, 1] - p[:, 0]
        d2 = p[:, 2] - p[:, 0]
        det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]  # 2 A
        # ∇N1 = (y2 - y0, x0 - x2)/2A, ∇N2 = (y0 - y1, x1 - x0)/2A, ∇N0 = -(∇N1 + ∇N2)
        g1 = np.stack([d2[:, 1], -d2[:, 0]], axis=1) / det[:, None]
        g2 = np.stack([-d1[:, 1], d1[:, 0]], axis=1) / det[:, None]
        G = np.stack([-(g1 + g2), g1, g2], axis=1)
        G.setflags(write=False)
        object.__setattr__(mesh, "_shape_grads", G)
    return G


# ---------------------------------------------------------------------------------------
# pure constitutive and assembly functions


def deformation_gradients(u_elem: np.ndarray, G: np.ndarray) -> np.ndarray:
    """``F = I + Σ_a u_a ⊗ ∇N_a`` ``(T, 2, 2)`` from element displacements ``(T, 3, 2)``."""
    F = np.einsum("tai,taj->tij", u_elem, G)
    F[:, 0, 0] += 1.0
    F[:, 1, 1] += 1.0
    return F


def _det_inv(F: np.ndarray):
    J = F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]
    Finv = np.empty_like(F)
    Finv[:, 0, 0] = F[:, 1, 1]
    Finv[:, 1, 1] = F[:, 0, 0]
    Finv[:, 0, 1] = -F[:, 0, 1]
    Finv[:, 1, 0] = -F[:, 1, 0]
    Finv /= J[:, None, None]
    return J, Finv


def neohookean_energy_stress(F: np.ndarray, lam: float, mu: float, tangent: bool = True):
    """Energy density ``W (T,)``, stress ``P (T, 2, 2)`` and (optionally) the tangent
    ``A_iJkL = ∂P_iJ/∂F_kL`` ``(T, 2, 2, 2, 2)`` of the compressible neo-Hookean model.

    ``A = μ δ_ik δ_JL + λ F⁻¹_Ji F⁻¹_Lk + (μ − λ ln J) F⁻¹_Li F⁻¹_Jk``. Requires ``J > 0``.
    """
    J, Finv = _det_inv(F)
    lnJ = np.log(J)
    FinvT = np.swapaxes(Finv, 1, 2)
    I1 = np.einsum("tij,tij->t", F, F)
    W = 0.5 * mu * (I1 - 2.0 - 2.0 * lnJ) + 0.5 * lam * lnJ**2
    P = mu * (F - FinvT) + (lam * lnJ)[:, None, None] * FinvT
    if not tangent:
        return W, P, None
    eye = np.eye(2)
    A = mu * np.einsum("ik,JL->iJkL", eye, eye)[None]
    A = A + lam * np.einsum("tJi,tLk->tiJkL", Finv, Finv)
    A = A + (mu - lam * lnJ)[:, None, None, None, None] * np.einsum("tLi,tJk->tiJkL", Finv, Finv)
    return W, P, A


def svk_energy_stress(F: np.ndarray, lam: float, mu: float, tangent: bool = True):
    """St Venant-Kirchhoff ``W``, ``P = F S`` with ``S = 2 μ E + λ tr(E) I`` and tangent
    ``A_iJkL = δ_ik S_JL + F_iI C_IJKL F_kK`` (``C = λ δ_IJ δ_KL + μ(δ_IK δ_JL + δ_IL δ_JK)``)."""
    eye = np.eye(2)
    E = 0.5 * (np.einsum("tki,tkj->tij", F, F) - eye)
    trE = E[:, 0, 0] + E[:, 1, 1]
    W = mu * np.einsum("tij,tij->t", E, E) + 0.5 * lam * trE**2
    S = 2.0 * mu * E + lam * trE[:, None, None] * eye
    P = F @ S
    if not tangent:
        return W, P, None
    A = np.einsum("ik,tJL->tiJkL", eye, S)
    A = A + lam * np.einsum("tiJ,tkL->tiJkL", F, F)
    A = A + mu * (np.einsum("tiL,tkJ->tiJkL", F, F) + np.einsum("tiI,tkI,JL->tiJkL", F, F, eye))
    return W, P, A


_LAW_FUNCS = {"neohookean": neohookean_energy_stress, "svk": svk_energy_stress}


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


def neohookean_element_tangents(Finv: np.ndarray, lnJ: np.ndarray, G: np.ndarray, areas: np.ndarray,
                                lam: float, mu: float) -> np.ndarray:
    """Neo-Hookean element stiffness ``(T, 6, 6)`` without forming the 4th-order tangent.

    With ``h_a = F⁻ᵀ ∇N_a`` the tangent contracts to
    ``K_{ai,bk} = A_e [μ δ_ik ∇N_a·∇N_b + λ h_ai h_bk + (μ − λ ln J) h_bi h_ak]``
    (equal to :func:`element_tangents` of :func:`neohookean_energy_stress`'s ``A``).
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


# ---------------------------------------------------------------------------------------
# model


@dataclass(frozen=True)
class SolveInfo:
    """What a nonlinear solve did: Newton iterations (all load steps), load steps taken,
    final residual norm (free DOFs), minimum ``det F``."""

    iterations: int
    load_steps: int
    residual: float
    min_jacobian: float


class _State:
    """Everything evaluated at one displacement (internal, per Newton iterate)."""

    __slots__ = ("u", "energy", "fint", "J", "F", "Finv", "lnJ")


class HyperelasticModel:
    """Hyperelastic P1 model on ``mesh`` with ``fixed_nodes`` held (zero displacement
    unless ``fixed_values`` is given to a solve).

    ``law``: ``"neohookean"`` (default) or ``"svk"``. A state is in equilibrium when
    ``‖r_free‖ ≤ rtol · f_ref + atol``, ``f_ref`` the larger of the external load norm
    and the load balanced by the warm start. Linear systems: the reduced tangent is
    ordered by reverse Cuthill-McKee once and factorised as a banded Cholesky matrix
    (symmetric positive definite at stable states); when Cholesky fails (indefinite
    tangent) a sparse LU is used instead.
    """

    def __init__(
        self,
        mesh: TissueMesh,
        material: Material,
        fixed_nodes,
        *,
        law: str = "neohookean",
        rtol: float = 1e-9,
        atol: float = 1e-12,
        max_iter: int = 25,
    ):
        from riskplan.deformable.linear import _fixed_node_array

        if not isinstance(mesh, TissueMesh):
            raise InvalidInputError(f"mesh: expected a TissueMesh, got {type(mesh).__name__}")
        if not isinstance(material, Material):
            raise InvalidInputError(f"material: expected a Material, got {type(material).__name__}")
        if law not in LAWS:
            raise InvalidInputError(f"law: expected one of {LAWS}, got {law!r}")
        self.mesh = mesh
        self.material = material
        self.law = law
        self.rtol, self.atol, self.max_iter = float(rtol), float(atol), int(max_iter)
        self.fixed_nodes = _fixed_node_array(fixed_nodes, mesh.n_nodes)
        if self.fixed_nodes.size < 2:
            raise InvalidInputError("fixed_nodes: fix at least two distinct nodes (else a rotation is free)")
        self._law = _LAW_FUNCS[law]
        self._lam, self._mu = material.lame
        self._G = shape_gradients(mesh)
        self._areas = mesh.areas
        self._tri = mesh.triangles
        self._tri_flat = np.ascontiguousarray(mesh.triangles.ravel())
        n = 2 * mesh.n_nodes
        self._n = n
        mask = np.ones(n, dtype=bool)
        fixed_dofs = np.sort(np.concatenate([2 * self.fixed_nodes, 2 * self.fixed_nodes + 1]))
        mask[fixed_dofs] = False
        self.fixed_dofs = fixed_dofs
        self.free_dofs = np.flatnonzero(mask)
        self._build_pattern()

    def _build_pattern(self) -> None:
        """Index maps from the T·36 element-matrix entries to (a) the reduced CSC matrix
        and (b) the upper band of its RCM-permuted form (entries touching a fixed DOF,
        and for (b) lower-triangle entries, are dropped)."""
        from scipy import sparse
        from scipy.sparse.csgraph import reverse_cuthill_mckee

        dofs = (2 * self._tri[:, :, None] + np.arange(2)[None, None, :]).reshape(-1, 6)  # (T, 6)
        self._edofs = dofs
        nf = len(self.free_dofs)
        red = np.full(self._n, -1, dtype=np.int64)
        red[self.free_dofs] = np.arange(nf)
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
        # banded Cholesky layout (upper form of scipy.linalg.cholesky_banded)
        pattern = sparse.csc_matrix(
            (np.ones(self._nnz), self._csc_indices, self._csc_indptr), shape=self._csc_shape
        )
        perm = reverse_cuthill_mckee(pattern.tocsr(), symmetric_mode=True)
        pos = np.empty(nf, dtype=np.int64)
        pos[perm] = np.arange(nf)
        pr, pc = pos[r], pos[c]
        upper = pr <= pc
        bw = int(np.max(pc[upper] - pr[upper])) if np.any(upper) else 0
        self._band_perm = perm
        self._bw = bw
        self._band_sel = self._keep[upper]
        self._band_slot = (bw + pr[upper] - pc[upper]) * nf + pc[upper]
        self._band_size = (bw + 1) * nf

    # ---- pure evaluations -------------------------------------------------------------
    def _F(self, u_flat: np.ndarray) -> np.ndarray:
        return deformation_gradients(u_flat.reshape(-1, 2)[self._tri], self._G)

    def jacobians(self, u) -> np.ndarray:
        """``det F`` per element ``(T,)`` for displacements ``u (N, 2)``."""
        F = self._F(np.asarray(u, dtype=np.float64).reshape(-1))
        return F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]

    def _evaluate(self, u_flat: np.ndarray) -> _State:
        """Energy and internal forces at ``u``; ``energy is None`` if an element inverted."""
        st = _State()
        st.u = u_flat
        F = self._F(u_flat)
        J, Finv = _det_inv(F)
        st.F, st.J, st.Finv = F, J, Finv
        if np.any(J <= 0.0):  # also for SVK, whose energy does not forbid inversion
            st.energy = None
            return st
        if self.law == "neohookean":
            lnJ = np.log(J)
            FinvT = np.swapaxes(Finv, 1, 2)
            I1 = np.einsum("tij,tij->t", F, F)
            W = 0.5 * self._mu * (I1 - 2.0 - 2.0 * lnJ) + 0.5 * self._lam * lnJ**2
            P = self._mu * (F - FinvT) + (self._lam * lnJ)[:, None, None] * FinvT
            st.lnJ = lnJ
        else:
            W, P, _ = self._law(F, self._lam, self._mu, False)
        fe = element_forces(P, self._G, self._areas)
        fint = np.empty(self._n)
        n_nodes = self.mesh.n_nodes
        fint[0::2] = np.bincount(self._tri_flat, fe[:, :, 0].ravel(), minlength=n_nodes)
        fint[1::2] = np.bincount(self._tri_flat, fe[:, :, 1].ravel(), minlength=n_nodes)
        st.energy = float(self._areas @ W)
        st.fint = fint
        return st

    def _element_tangents(self, st: _State) -> np.ndarray:
        if self.law == "neohookean":
            return neohookean_element_tangents(st.Finv, st.lnJ, self._G, self._areas, self._lam, self._mu)
        _, _, A = self._law(st.F, self._lam, self._mu, True)
        return element_tangents(A, self._G, self._areas)

    def _csc(self, Ke_flat: np.ndarray):
        data = np.bincount(self._slot, Ke_flat[self._keep], minlength=self._nnz)
        from scipy import sparse

        return sparse.csc_matrix((data, self._csc_indices, self._csc_indptr), shape=self._csc_shape)

    def _factor(self, st: _State):
        """A solver ``r -> K⁻¹ r`` for the reduced tangent at ``st``."""
        import scipy.linalg

        Ke = self._element_tangents(st).reshape(-1)
        ab = np.bincount(self._band_slot, Ke[self._band_sel], minlength=self._band_size)
        ab = ab.reshape(self._bw + 1, -1)
        try:
            cb = scipy.linalg.cholesky_banded(ab, lower=False, check_finite=False)
        except np.linalg.LinAlgError:
            from scipy.sparse.linalg import splu

            try:
                lu = splu(self._csc(Ke))
            except RuntimeError as exc:
                raise ConvergenceError(f"Newton: singular tangent ({exc})") from exc
            return lu.solve
        from riskplan.deformable.linear import BandedCholeskySolver

        return BandedCholeskySolver(cb, self._band_perm)

    def _check_u(self, u, name="u") -> np.ndarray:
        return as_array(u, name, shape=(self.mesh.n_nodes, 2)).reshape(-1).copy()

    def _evaluate_checked(self, u) -> _State:
        st = self._evaluate(self._check_u(u))
        if st.energy is None:
            self._raise_inverted(st.J)
        return st

    def energy(self, u) -> float:
        """Stored energy ``Σ_e A_e W(F_e)``; raises :class:`ElementInversionError` if some
        ``det F ≤ 0`` (for both laws: an inverted element is not a physical state)."""
        return self._evaluate_checked(u).energy

    def internal_forces(self, u) -> np.ndarray:
        """Internal nodal forces ``f_int (N, 2)`` (all nodes, reactions included)."""
        return self._evaluate_checked(u).fint.reshape(-1, 2)

    def residual(self, u, nodal_forces) -> np.ndarray:
        """``f_int(u) − f_ext`` ``(N, 2)``, zero at fixed nodes."""
        f = as_array(nodal_forces, "nodal_forces", shape=(self.mesh.n_nodes, 2)).reshape(-1)
        r = self.internal_forces(u).reshape(-1) - f
        r[self.fixed_dofs] = 0.0
        return r.reshape(-1, 2)

    def tangent(self, u, *, full: bool = False):
        """Tangent stiffness ``∂f_int/∂u`` at ``u (N, 2)``: the reduced ``(n_free, n_free)``
        CSC matrix over ``free_dofs`` (default) or, with ``full=True``, the ``(2N, 2N)``
        CSR matrix over all DOFs."""
        st = self._evaluate_checked(u)
        Ke = self._element_tangents(st)
        if not full:
            return self._csc(Ke.reshape(-1))
        r = np.repeat(self._edofs, 6, axis=1).ravel()
        c = np.tile(self._edofs, (1, 6)).ravel()
        from scipy import sparse

        return sparse.csr_matrix((Ke.ravel(), (r, c)), shape=(self._n, self._n))

    def _raise_inverted(self, J: np.ndarray, context: str = ""):
        bad = np.flatnonzero(J <= 0.0)
        raise ElementInversionError(
            f"{bad.size} element(s) inverted (det F <= 0){context}: elements {bad[:10].tolist()}, "
            f"min det F = {float(J.min()):.3g}",
            elements=bad,
            min_jacobian=float(J.min()),
        )

    # ---- Newton -------------------------------------------------------------------
    def _newton(self, u: np.ndarray, f: np.ndarray, fscale: float):
        """Newton + backtracking on Π from ``u`` (flat) for the load ``f`` (flat).
        Returns (u, iterations, residual) or raises."""
        free = self.free_dofs
        st = self._evaluate(u)
        if st.energy is None:
            self._raise_inverted(st.J, " at the start of a load step")
        tol = self.rtol * fscale + self.atol
        f_free = f[free]
        r = st.fint[free] - f_free
        rn = float(np.linalg.norm(r))
        for it in range(self.max_iter + 1):
            if rn <= tol:
                return st.u, it, rn
            if it == self.max_iter:
                break
            try:
                du = -self._factor(st)(r)
            except ConvergenceError as exc:
                exc.residual, exc.iterations = rn, it
                raise
            pi0 = st.energy - float(f @ st.u)
            slope = float(r @ du)  # directional derivative of Π along du
            if not slope < 0.0:
                # not a descent direction (indefinite tangent): steepest descent instead
                du = -r
                slope = -rn * rn
            alpha = 1.0
            J_bad = None
            for _ in range(40):
                trial = st.u.copy()
                trial[free] += alpha * du
                st1 = self._evaluate(trial)
                if st1.energy is None:
                    J_bad = st1.J
                    alpha *= 0.5
                    continue
                r1 = st1.fint[free] - f_free
                rn1 = float(np.linalg.norm(r1))
                # Armijo on Π, or (near the solution, where Π is flat to round-off)
                # a decrease of the residual norm
                if st1.energy - float(f @ trial) <= pi0 + 1e-4 * alpha * slope or rn1 < 0.5 * rn:
                    break
                alpha *= 0.5
            else:
                if J_bad is not None:
                    self._raise_inverted(J_bad, " in every line-search trial")
                raise ConvergenceError(f"Newton line search failed (residual {rn:.3g})", residual=rn, iterations=it)
            st, r, rn = st1, r1, rn1
        raise ConvergenceError(
            f"Newton did not converge in {self.max_iter} iterations (residual {rn:.3g}, tolerance {tol:.3g})",
            residual=rn,
            iterations=self.max_iter,
        )

    def _dirichlet_predictor(self, u: np.ndarray, dub: np.ndarray) -> np.ndarray:
        """Move the fixed DOFs by ``dub`` and the free ones by the linearised response
        ``−K_ff⁻¹ K_fc dub`` (tangent at ``u``), so a prescribed motion does not crush
        the elements next to the supports."""
        st = self._evaluate(u)
        if st.energy is None:
            self._raise_inverted(st.J, " before a prescribed-displacement increment")
        Kfull = self.tangent(u.reshape(-1, 2), full=True)
        rhs = Kfull[self.free_dofs][:, self.fixed_dofs] @ dub
        out = u.copy()
        out[self.fixed_dofs] += dub
        out[self.free_dofs] -= self._factor(st)(rhs)
        return out

    @one_blas_thread
    def solve_with_info(
        self, nodal_forces, u0=None, *, fixed_values=None, load_steps: int = 1, max_halvings: int = 8
    ):
        """Equilibrium displacement ``(N, 2)`` under dead nodal loads, plus :class:`SolveInfo`.

        ``u0 (N, 2)``: warm start (an equilibrium state, e.g. the previous simulator state);
        the load path then runs from ``f_int(u0)`` (the load ``u0`` balances) to
        ``nodal_forces``, and the fixed nodes from ``u0``'s values to ``fixed_values
        (F, 2)`` (prescribed displacements of ``fixed_nodes`` in sorted node order; default
        zero), in ``load_steps`` equal increments (a prescribed-motion increment starts
        from a linearised predictor). A failed increment is halved (up to
        ``max_halvings`` halvings per solve) and grows back after increments that
        converge in at most 4 iterations. Raises :class:`ElementInversionError` (names
        the elements) or :class:`ConvergenceError` (carries the residual).
        Deterministic: the result depends only on the arguments.
        """
        f = as_array(nodal_forces, "nodal_forces", shape=(self.mesh.n_nodes, 2)).reshape(-1).copy()
        f[self.fixed_dofs] = 0.0
        if isinstance(load_steps, bool) or not isinstance(load_steps, (int, np.integer)) or load_steps < 1:
            raise InvalidInputError(f"load_steps: expected an int >= 1, got {load_steps!r}")
        if fixed_values is None:
            ub = np.zeros(len(self.fixed_dofs))
        else:
            ub = as_array(fixed_values, "fixed_values", shape=(len(self.fixed_nodes), 2)).reshape(-1)
        if u0 is None:
            u = np.zeros(self._n)
            f0 = np.zeros(self._n)
        else:
            u = self._check_u(u0, "u0")
            st = self._evaluate(u)
            if st.energy is None:
                self._raise_inverted(st.J, " in u0")
            f0 = st.fint.copy()
            f0[self.fixed_dofs] = 0.0
        ub0 = u[self.fixed_dofs].copy()
        moving = bool(np.any(ub != ub0))
        fscale = max(float(np.linalg.norm(f[self.free_dofs])), float(np.linalg.norm(f0[self.free_dofs])))
        if moving:
            # forces of the order the prescribed motion produces: linear response to it
            probe = np.zeros(self._n)
            probe[self.fixed_dofs] = ub - ub0
            st = self._evaluate(probe)
            if st.energy is not None:
                fscale = max(fscale, float(np.linalg.norm(st.fint[self.fixed_dofs])))
        if fscale == 0.0:
            fscale = 1.0
        s, ds = 0.0, 1.0 / int(load_steps)
        iters, steps, halvings = 0, 0, 0
        rn = 0.0
        while s < 1.0 - 1e-15:
            s1 = min(1.0, s + ds)
            fs = f if s1 == 1.0 else f0 + s1 * (f - f0)
            try:
                start = u
                if moving:
                    target = ub if s1 == 1.0 else ub0 + s1 * (ub - ub0)
                    start = self._dirichlet_predictor(u, target - u[self.fixed_dofs])
                u_new, it, rn = self._newton(start, fs, fscale)
            except (ConvergenceError, ElementInversionError) as exc:
                if halvings >= max_halvings:
                    raise exc
                halvings += 1
                ds *= 0.5
                logger.debug("load step %.3g -> %.3g failed (%s); halving", s, s1, exc)
                continue
            iters += it
            steps += 1
            u, s = u_new, s1
            if it <= 4:  # an easy increment: let the next one grow back towards 1/load_steps
                ds = min(2.0 * ds, 1.0 / int(load_steps))
        J = self.jacobians(u.reshape(-1, 2))
        return u.reshape(-1, 2), SolveInfo(iterations=iters, load_steps=steps, residual=rn, min_jacobian=float(J.min()))

    def solve(self, nodal_forces, u0=None, *, fixed_values=None, load_steps: int = 1) -> np.ndarray:
        """Equilibrium displacement ``(N, 2)``; see :meth:`solve_with_info`."""
        return self.solve_with_info(nodal_forces, u0, fixed_values=fixed_values, load_steps=load_steps)[0]


class NeoHookeanModel(HyperelasticModel):
    """:class:`HyperelasticModel` with the compressible neo-Hookean law."""

    def __init__(self, mesh: TissueMesh, material: Material, fixed_nodes, **kw):
        super().__init__(mesh, material, fixed_nodes, law="neohookean", **kw)
