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
so ``u.reshape(N, 3)`` is the nodal displacement. Linear systems (:mod:`.tetfactor`): banded
Cholesky in reverse Cuthill-McKee order (sparse LU for a tangent that is not positive
definite), and the band of ``K⁻¹`` by selected inversion (:meth:`TetTissue.element_green_blocks`).
Material points: ``TetMaterialPoints`` (:mod:`.tetlocate`), the base class.

Newton's method for the neo-Hookean law: full Newton with the consistent tangent, a
backtracking line search on the potential ``Π(u) = Σ_e V_e W(F_e) − f·u`` that also
rejects steps inverting an element, load stepping with halving of failed increments;
failure raises :class:`~riskplan.errors.ConvergenceError` (never a silent ``u = 0``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_array, check_choice, check_instance
from riskplan.deformable.hyperelastic import SolveInfo
from riskplan.deformable.material import Material
from riskplan.deformable.tetassembly import (
    _norm,
    _pattern,
    deformation_gradients,
    element_stiffness,
    linear_stiffness_parts,
    neohookean_stress,
    support_dofs,
)
from riskplan.deformable.tetfactor import factor_reduced
from riskplan.deformable.tetlocate import TetMaterialPoints
from riskplan.deformable.tetmesh import TetMesh
from riskplan.deformable.tetnewton import solve_nonlinear
from riskplan.errors import ConvergenceError, ElementInversionError, InvalidInputError
from riskplan.threads import one_blas_thread

#: The pure parts live in :mod:`.tetassembly`, :mod:`.tetfactor`, :mod:`.tetlocate` (the
#: material-point queries, ``TetMaterialPoints``, ``locate3d``, ``find_points``,
#: ``sphere_points``) and :mod:`.tetnewton`, and are imported from there.
__all__ = ["TetTissue", "TissueState3D"]

logger = logging.getLogger(__name__)

LAWS3D = ("linear", "neo-hookean")


@dataclass(frozen=True, eq=False)
class TissueState3D:
    """What :meth:`TetTissue.snapshot` saves: the displacement ``(N, 3)`` and the nodal
    load ``(N, 3)`` it balances (read-only copies), and the mesh size it belongs to."""

    displacement: np.ndarray
    load: np.ndarray
    n_nodes: int

    def __setstate__(self, state: dict) -> None:
        # unpickled arrays come back writeable: make them read-only again
        for k, v in state.items():
            if isinstance(v, np.ndarray):
                v.setflags(write=False)
            object.__setattr__(self, k, v)

    def identical(self, other: TissueState3D) -> bool:
        """Bit-for-bit equality (the snapshot/restore contract).

        Parameters
        ----------
        other : TissueState3D
            Another state.

        Returns
        -------
        bool
        """
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


class TetTissue(TetMaterialPoints):
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
        check_instance(mesh, TetMesh, "mesh")
        check_instance(material, Material, "material")
        check_choice(law, LAWS3D, "law")
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
        fixed, extra, self.fixed_dofs, self.free_dofs = support_dofs(mesh, fixed_nodes, fixed_dofs)
        self.fixed_nodes = fixed
        self._fixed_dofs_arg = extra
        self._pattern = _pattern(mesh.tets, self.free_dofs, n)
        self._lam, self._mu = material.lam3d, material.mu
        self._G = mesh.shape_gradients
        self._V = mesh.volumes
        self._u = np.zeros(n)
        self._f = np.zeros(n)
        self._parts = _parts
        self._linear_solver = None
        self._K_fc = None
        self._green = None  # element_green_blocks, on first use
        if law == "linear":
            self._factorise_linear()

    # ---- construction ------------------------------------------------------------------
    def _linear_parts(self):
        """``(K_λ, K_μ)`` element matrices ``(T·144,)`` (flat) of the linear stiffness with
        ``(λ, μ) = (1, 0)`` and ``(0, 1)``."""
        if self._parts is None:
            self._parts = linear_stiffness_parts(self._G, self._V)
        return self._parts

    @one_blas_thread
    def _factorise_linear(self) -> None:
        Kl, Km = self._linear_parts()
        self._linear_solver = factor_reduced(self._pattern, self._lam * Kl + self._mu * Km, True)

    def with_material(self, material: Material) -> TetTissue:
        """The same mesh, supports and law with another material (a material draw).

        Re-uses the sparsity layout and, for the linear law, the assembled parts
        ``K = λ K_λ + μ K_μ`` (only the factorisation is new). The new tissue is at rest.

        Parameters
        ----------
        material : Material
            The drawn material (``E``, ``nu``).

        Returns
        -------
        TetTissue
            A new tissue; this one is unchanged.
        """
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
        state["_green"] = None
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
        """The current state (read-only copies).

        Returns
        -------
        TissueState3D
            Displacement ``(N, 3)``, the load ``(N, 3)`` it balances, and ``n_nodes``.
        """
        return TissueState3D(
            displacement=_frozen(self._u.reshape(-1, 3)),
            load=_frozen(self._f.reshape(-1, 3)),
            n_nodes=self.mesh.n_nodes,
        )

    def restore(self, state: TissueState3D) -> None:
        """Make a saved state current (bit for bit).

        Parameters
        ----------
        state : TissueState3D
            From :meth:`snapshot` of a tissue on a mesh with the same node count.
        """
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
        """Stored energy ``Σ_e V_e W(F_e)`` (linear law: ``½ uᵀ K u``).

        Parameters
        ----------
        u : array_like, shape (N, 3), optional
            Nodal displacement; ``None``: the current state.

        Returns
        -------
        float

        Raises
        ------
        ElementInversionError
            Some element has ``det F ≤ 0`` (neo-Hookean).
        """
        e, _, J, _, _ = self._internal(self._field(u).reshape(-1).copy())
        if e is None:
            self._raise_inverted(J)
        return e

    def internal_forces(self, u=None) -> np.ndarray:
        """Internal nodal forces ``f_int,a = Σ_e V_e P_e ∇N_a`` at all nodes (reactions included).

        Parameters
        ----------
        u : array_like, shape (N, 3), optional
            Nodal displacement; ``None``: the current state.

        Returns
        -------
        ndarray, shape (N, 3)
        """
        e, fint, J, _, _ = self._internal(self._field(u).reshape(-1).copy())
        if e is None:
            self._raise_inverted(J)
        return fint.reshape(-1, 3)

    def residual(self, u, nodal_forces) -> np.ndarray:
        """Out-of-balance forces ``f_int(u) − f``, zero at the fixed DOFs.

        Parameters
        ----------
        u : array_like, shape (N, 3)
            Nodal displacement.
        nodal_forces : array_like, shape (N, 3)
            External nodal forces.

        Returns
        -------
        ndarray, shape (N, 3)
        """
        f = as_array(nodal_forces, "nodal_forces", shape=(self.mesh.n_nodes, 3)).reshape(-1)
        r = self.internal_forces(u).reshape(-1) - f
        r[self.fixed_dofs] = 0.0
        return r.reshape(-1, 3)

    def reactions(self, u=None) -> np.ndarray:
        """Support reactions: ``f_int`` at the fixed nodes.

        Parameters
        ----------
        u : array_like, shape (N, 3), optional
            Nodal displacement; ``None``: the current state.

        Returns
        -------
        ndarray, shape (F, 3)
            In sorted ``fixed_nodes`` order.
        """
        return self.internal_forces(u)[self.fixed_nodes]

    def tangent(self, u=None, *, full: bool = False):
        """Tangent stiffness ``∂f_int/∂u`` (linear law: ``K``).

        Parameters
        ----------
        u : array_like, shape (N, 3), optional
            Nodal displacement; ``None``: the current state.
        full : bool
            ``False``: the reduced matrix over ``free_dofs``; ``True``: over all DOFs.

        Returns
        -------
        scipy.sparse matrix
            CSC ``(n_free, n_free)`` or CSR ``(3N, 3N)``.
        """
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
        """``K_ff⁻¹ f_free`` with the cached factorisation (linear law; hot path, no validation).

        Parameters
        ----------
        f_free : ndarray, shape (n_free,) or (n_free, k)
            Forces at ``free_dofs``.

        Returns
        -------
        ndarray
            Displacements at ``free_dofs``, same shape.
        """
        return self._linear_solver(f_free)

    @one_blas_thread
    def element_green_blocks(self) -> np.ndarray:
        """``K⁻¹`` over each element's 12 DOFs (linear law; computed once per tissue).

        ``G[e, 3a + i, 3b + k]`` is displacement ``i`` of the element's node ``a`` under a
        unit force ``k`` at its node ``b`` (zero rows and columns at fixed DOFs), taken from
        the band of ``K⁻¹`` by selected inversion of the cached factor
        (``riskplan.deformable.tetfactor.band_inverse``): ``O(n b²)``, the cost of the
        factorisation, instead of a solve per node.

        Returns
        -------
        numpy.ndarray, shape (T, 12, 12)
            Read-only; equal to the columns of solves up to round-off.

        Raises
        ------
        InvalidInputError
            The tissue is not linear (its tangent changes with the state).
        """
        if self.law != "linear":
            raise InvalidInputError("element_green_blocks: the linear law only")
        G = self._green
        if G is None:
            from riskplan.deformable.tetfactor import band_inverse, element_band_index

            idx = self._pattern.__dict__.get("_green_index")
            if idx is None:  # once per mesh and support set (the pattern is shared)
                p = self._pattern
                idx = element_band_index(
                    p.element_dofs, self.free_dofs, self._n, p.band_perm, p.bandwidth
                )
                p.__dict__["_green_index"] = idx
            zb = band_inverse(self._linear_solver.cb)
            G = np.append(zb.ravel(), 0.0)[idx]
            G.setflags(write=False)
            self._green = G
        return G

    def solve(self, nodal_forces, *, fixed_values=None, load_steps: int = 1) -> np.ndarray:
        """Equilibrium displacement under nodal forces; it becomes the current state.

        Parameters
        ----------
        nodal_forces : array_like, shape (N, 3)
            External nodal forces (entries at fixed DOFs are ignored).
        fixed_values : array_like, optional
            Prescribed displacements of the fixed DOFs (see :meth:`solve_with_info`).
        load_steps : int
            Load increments of a neo-Hookean solve.

        Returns
        -------
        ndarray, shape (N, 3)
            See :meth:`solve_with_info` (errors included).
        """
        return self._solve(nodal_forces, fixed_values, load_steps, info=False)[0]

    def solve_with_info(self, nodal_forces, *, fixed_values=None, load_steps: int = 1):
        """Equilibrium displacement and what the solver did; it becomes the current state.

        Linear law: ``u_f = K_ff⁻¹ (f_f − K_fc ū)`` with the cached factorisation.
        Neo-Hookean: Newton from the current state, the load (and the prescribed values) ramped
        from the current ones in ``load_steps`` increments, a failed increment halved up to 8
        times.

        Parameters
        ----------
        nodal_forces : array_like, shape (N, 3)
            External nodal forces (entries at fixed DOFs are ignored).
        fixed_values : array_like, optional
            Prescribed displacements of the fixed DOFs in ``fixed_dofs`` order (sorted flat DOF
            index; ``(F, 3)`` in sorted node order when only ``fixed_nodes`` are given); default 0.
        load_steps : int
            Load increments (>= 1) of a neo-Hookean solve.

        Returns
        -------
        u : ndarray, shape (N, 3)
            Nodal displacement.
        info : SolveInfo
            Newton iterations, load steps, final residual norm, minimum ``det F`` (linear
            law: 0 iterations, 1 step, the residual ``‖K u − f‖`` and ``det(I + ∇u)``
            evaluated).

        Raises
        ------
        ConvergenceError
            Newton did not converge (residual and iterations attached); the state is unchanged.
        ElementInversionError
            Every trial inverted an element; the state is unchanged.
        """
        return self._solve(nodal_forces, fixed_values, load_steps, info=True)

    @one_blas_thread
    def _solve(self, nodal_forces, fixed_values, load_steps, info: bool):
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
                if self._K_fc is None:  # the coupling block, once per tissue
                    Kfull = self.tangent(full=True)
                    self._K_fc = Kfull[self.free_dofs][:, self.fixed_dofs].tocsr()
                rhs = rhs - self._K_fc @ ub
            u[self.free_dofs] = self._linear_solver(rhs)
            if not np.all(np.isfinite(u)):
                raise ConvergenceError(
                    "linear solve: the displacement overflows float64 (loads too large)",
                    residual=float("inf"),
                    iterations=0,
                )
            self._u, self._f = u, f
            if not info:
                return u.reshape(-1, 3).copy(), None
            # the residual of the solve and det F, evaluated (not assumed) for the report
            _, fint, _, _, _ = self._internal(u)
            rn = _norm((fint - f)[self.free_dofs])
            min_j = float(np.linalg.det(self._F(u)).min())
            return u.reshape(-1, 3).copy(), SolveInfo(0, 1, rn, min_j)
        return solve_nonlinear(self, f, ub, int(load_steps))

    def __repr__(self) -> str:
        return (
            f"TetTissue(law={self.law!r}, E={self.material.E:g}, nu={self.material.nu:g}, "
            f"n_elements={self.mesh.n_elements}, fixed_nodes={self.fixed_nodes.size})"
        )
