r"""Geometrically nonlinear (hyperelastic) P1 FEM: compressible neo-Hookean and
St Venant-Kirchhoff (paper V-B: "a geometrically nonlinear FEM simulator to accurately
simulate the large deformations of the object").

Total Lagrangian form. With deformation gradient ``F = I + ∇_X u`` (constant per P1
element), ``J = det F``, ``I₁ = tr(FᵀF)``, the stored energies (per unit reference area)

* neo-Hookean (2-D, plane strain), with its first Piola-Kirchhoff stress:

  .. math::

      W = \tfrac{\mu}{2} (I_1 - 2 - 2 \ln J) + \tfrac{\lambda}{2} (\ln J)^2, \qquad
      P = \mu (F - F^{-\top}) + \lambda \ln J \, F^{-\top}

* St Venant-Kirchhoff:

  .. math::

      E = \tfrac12 (F^\top F - I), \qquad W = \mu\, E : E + \tfrac{\lambda}{2} (\operatorname{tr} E)^2,
      \qquad P = F (2 \mu E + \lambda \operatorname{tr} E \, I)

both linearise at ``F = I`` to ``σ = λ tr(ε) I + 2 μ ε``. We use ``(λ, μ) = Material.lame``:
for ``plane="strain"`` this is the exact plane-strain neo-Hookean model; for
``plane="stress"`` it is the 2-D model with the plane-stress λ₂ = Eν/(1−ν²), which equals
plane-stress linear elasticity at small strain (a thin-sheet model would need the
out-of-plane stretch as an extra unknown; we do not model it).

Equilibrium on the free DOFs (the FEM residual), with its tangent:

.. math::

    r(u) = f_{\mathrm{int}}(u) - f_{\mathrm{ext}} = 0, \qquad
    f_{\mathrm{int},a} = \sum_e A_e P_e \nabla N_a, \qquad
    K_{ai,bk} = \sum_e A_e \frac{\partial P_{iJ}}{\partial F_{kL}} \nabla N_{aJ} \nabla N_{bL}

This module is the model (evaluations at a displacement, warm starts, the solve's checks);
the pieces are pure functions elsewhere: element kinematics (``F``, ``det F``, ``F⁻¹``) in
:mod:`.elements`, the laws in :mod:`.laws`, element forces/tangents and the sparse layouts in
:mod:`.assembly`, banded Cholesky in :mod:`.banded`, and Newton's method in :mod:`.newton`:
a backtracking line search on the total potential energy ``Π(u) = Σ_e A_e W(F_e) − f_ext·u``
that also rejects steps inverting an element (``det F ≤ 0``), and load stepping (adaptive
halving).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from riskplan._validation import as_array, check_choice, check_instance
from riskplan.deformable.assembly import (
    TangentPattern,
    element_forces,
    element_tangents,
    fixed_node_array,
    neohookean_element_tangents,
    split_dofs,
)
from riskplan.deformable.banded import cached_layout
from riskplan.deformable.elements import deformation_gradients, determinants_and_inverses
from riskplan.deformable.laws import LAWS, neohookean_energy_and_stress
from riskplan.deformable.material import Material
from riskplan.deformable.mesh import TissueMesh
from riskplan.deformable.newton import (
    SolveInfo,
    factor_tangent,
    line_search_failure,
    load_path,
    stable_norm,
)
from riskplan.deformable.nhkernels import neohookean_evaluate
from riskplan.errors import ElementInversionError, InvalidInputError
from riskplan.threads import one_blas_thread

# SolveInfo and line_search_failure are defined in riskplan.deformable.newton and handed on
# from here (the 3-D tissue's solver takes them from this module)
__all__ = ["HyperelasticModel", "NeoHookeanModel", "SolveInfo", "line_search_failure"]


class _State:
    """Everything evaluated at one displacement (internal, per Newton iterate); ``solver``
    is the factorised tangent there, built on first use."""

    __slots__ = ("F", "Finv", "J", "energy", "fint", "lnJ", "solver", "u")

    def __init__(self):
        self.solver = None


# least time of one load step (at least one Newton iteration), for the work budget: a tenth
# or less of the measured 0.39 ms (50 elements), 0.83 ms (175) and 6.4 ms (1000) per iteration
# (2-core AMD EPYC, shared), so that a refusal never rests on a slow machine's figure
NEWTON_FIXED_S = 50e-6
NEWTON_ELEMENT_S = 1e-6

# evaluated start displacements (with their factorised tangents) a model keeps: solves
# restarted from the same few states (the linearisation's runs from a plan's states) reuse them
START_CACHE = 4

# sparsity layouts by (triangles, free DOFs): models of one mesh with different materials
# (a parameter distribution's draws) share one; a layout is never modified after it is built
_PATTERNS: OrderedDict = OrderedDict()
_PATTERN_CACHE = 8


def _tangent_pattern(triangles: np.ndarray, free_dofs: np.ndarray, n_dofs: int) -> TangentPattern:
    return cached_layout(_PATTERNS, TangentPattern, triangles, free_dofs, n_dofs, _PATTERN_CACHE)


class HyperelasticModel:
    """Hyperelastic P1 model on ``mesh`` with ``fixed_nodes`` held (zero displacement
    unless ``fixed_values`` is given to a solve).

    ``law``: ``"neohookean"`` (default) or ``"svk"``. A state is in equilibrium when
    ``‖r_free‖ ≤ rtol · f_ref + atol``, ``f_ref`` the larger of the external load norm
    and the load balanced by the warm start. Linear systems: the reduced tangent is
    ordered by reverse Cuthill-McKee once and factorised as a banded Cholesky matrix
    (symmetric positive definite at stable states); when Cholesky fails (indefinite
    tangent) a sparse LU is used instead. The model keeps its last ``START_CACHE``
    evaluated start displacements with their factorisations (keyed by the exact
    displacement), so solves restarted from one state share that work; results are those
    of a fresh model, bit for bit.
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
        check_instance(mesh, TissueMesh, "mesh")
        check_instance(material, Material, "material")
        check_choice(law, LAWS, "law")
        self.mesh = mesh
        self.material = material
        self.law = law
        self.rtol, self.atol, self.max_iter = float(rtol), float(atol), int(max_iter)
        # rtol >= 1 would accept the unloaded start under any load (zero iterations, u = 0)
        if not (0.0 < self.rtol < 1.0) or not (0.0 <= self.atol < np.inf) or self.max_iter < 1:
            raise InvalidInputError(
                f"rtol, atol, max_iter: expected 0 < rtol < 1, finite atol >= 0, max_iter >= 1; "
                f"got {rtol!r}, {atol!r}, {max_iter!r}"
            )
        self.fixed_nodes = fixed_node_array(fixed_nodes, mesh.n_nodes)
        if self.fixed_nodes.size < 2:
            raise InvalidInputError(
                "fixed_nodes: fix at least two distinct nodes (else a rotation is free)"
            )
        self._law = LAWS[law]
        self._lam, self._mu = material.lame
        self._G = mesh.shape_gradients
        self._areas = mesh.areas
        self._tri = mesh.triangles
        self._tri_flat = np.ascontiguousarray(mesh.triangles.ravel())
        self._n = 2 * mesh.n_nodes
        self.fixed_dofs, self.free_dofs = split_dofs(self.fixed_nodes, self._n)
        self._pattern = _tangent_pattern(self._tri, self.free_dofs, self._n)
        self._starts: OrderedDict = OrderedDict()
        # the neo-Hookean law runs compiled (riskplan.deformable.nhkernels); ``compiled =
        # False`` selects the array path (the reference the kernels are tested against)
        self.compiled = law == "neohookean"
        self._tri64 = np.ascontiguousarray(mesh.triangles, dtype=np.int64)
        self._Gc = np.ascontiguousarray(self._G, dtype=np.float64)
        self._areas_c = np.ascontiguousarray(self._areas, dtype=np.float64)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_starts"] = OrderedDict()
        return state

    def _start(self, u_flat: np.ndarray) -> _State:
        """:meth:`_evaluate` of a solve's start, from a small cache keyed by the exact
        displacement (the state and its factorisation are pure functions of it, so a hit
        changes no result). The cached ``u`` is private: callers copy before returning it."""
        key = u_flat.tobytes()
        st = self._starts.get(key)
        if st is None:
            st = self._evaluate(u_flat.copy())
            self._starts[key] = st
            if len(self._starts) > START_CACHE:
                self._starts.popitem(last=False)
        else:
            self._starts.move_to_end(key)
        return st

    # ---- pure evaluations -------------------------------------------------------------
    def _F(self, u_flat: np.ndarray) -> np.ndarray:
        return deformation_gradients(u_flat.reshape(-1, 2)[self._tri], self._G)

    def jacobians(self, u) -> np.ndarray:
        r"""``J = det F`` per element, ``F = I + \sum_a u_a \otimes \nabla N_a``.

        Parameters
        ----------
        u : array_like, shape (N, 2)
            Nodal displacements (``N = mesh.n_nodes``).

        Returns
        -------
        numpy.ndarray, shape (T,)
            One per triangle; ``≤ 0`` where an element is inverted.
        """
        F = self._F(np.asarray(u, dtype=np.float64).reshape(-1))
        return F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]

    def _evaluate(self, u_flat: np.ndarray) -> _State:
        """Energy and internal forces at ``u``; ``energy is None`` if an element inverted."""
        if self.compiled:
            return self._evaluate_compiled(u_flat)
        st = _State()
        st.u = u_flat
        F = self._F(u_flat)
        J, Finv = determinants_and_inverses(F)
        st.F, st.J, st.Finv = F, J, Finv
        if np.any(J <= 0.0):  # also for SVK, whose energy does not forbid inversion
            st.energy = None
            return st
        if self.law == "neohookean":
            lnJ = np.log(J)
            W, P = neohookean_energy_and_stress(F, Finv, lnJ, self._lam, self._mu)
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

    def _evaluate_compiled(self, u_flat: np.ndarray) -> _State:
        """``_evaluate`` of the neo-Hookean law by ``nhkernels.neohookean_evaluate``
        (``st.F`` is not kept: the neo-Hookean tangent needs ``F⁻¹`` and ``ln J`` only)."""
        st = _State()
        st.u = u_flat
        T = self._tri64.shape[0]
        st.fint = np.empty(self._n)
        st.Finv = np.empty((T, 2, 2))
        st.lnJ = np.empty(T)
        st.J = np.empty(T)
        st.F = None
        energy, inverted = neohookean_evaluate(
            np.ascontiguousarray(u_flat, dtype=np.float64),
            self._tri64,
            self._Gc,
            self._areas_c,
            self._lam,
            self._mu,
            st.fint,
            st.Finv,
            st.lnJ,
            st.J,
        )
        st.energy = None if inverted else float(energy)
        return st

    def _element_tangents(self, st: _State) -> np.ndarray:
        if self.law == "neohookean":
            return neohookean_element_tangents(
                st.Finv, st.lnJ, self._G, self._areas, self._lam, self._mu
            )
        _, _, A = self._law(st.F, self._lam, self._mu, True)
        return element_tangents(A, self._G, self._areas)

    def _factor(self, st: _State):
        """A solver ``r -> K⁻¹ r`` for the reduced tangent at ``st`` (kept on ``st``)."""
        if st.solver is None:
            st.solver = factor_tangent(self, st)
        return st.solver

    def _check_u(self, u, name="u") -> np.ndarray:
        return as_array(u, name, shape=(self.mesh.n_nodes, 2)).reshape(-1).copy()

    def _evaluate_checked(self, u) -> _State:
        st = self._evaluate(self._check_u(u))
        if st.energy is None:
            self._raise_inverted(st.J)
        return st

    def energy(self, u) -> float:
        r"""Stored energy; raises :class:`ElementInversionError` if some ``det F ≤ 0`` (for
        both laws: an inverted element is not a physical state).

        .. math::

            E(u) = \sum_e A_e\, W(F_e)

        Parameters
        ----------
        u : array_like, shape (N, 2)
            Nodal displacements (``N = mesh.n_nodes``).

        Returns
        -------
        float
            In energy units of the material (``E`` times area).
        """
        return self._evaluate_checked(u).energy

    def internal_forces(self, u) -> np.ndarray:
        r"""Internal nodal forces (all nodes, reactions included):

        .. math::

            f_{\mathrm{int},a} = \sum_e A_e P(F_e) \nabla N_a

        Parameters
        ----------
        u : array_like, shape (N, 2)
            Nodal displacements (``N = mesh.n_nodes``).

        Returns
        -------
        numpy.ndarray, shape (N, 2)
        """
        return self._evaluate_checked(u).fint.reshape(-1, 2)

    def residual(self, u, nodal_forces) -> np.ndarray:
        """The FEM residual ``r = f_int(u) − f_ext``, zero at fixed nodes.

        Parameters
        ----------
        u : array_like, shape (N, 2)
            Nodal displacements (``N = mesh.n_nodes``).
        nodal_forces : array_like, shape (N, 2)
            External nodal loads ``f_ext``.

        Returns
        -------
        numpy.ndarray, shape (N, 2)
        """
        f = as_array(nodal_forces, "nodal_forces", shape=(self.mesh.n_nodes, 2)).reshape(-1)
        r = self.internal_forces(u).reshape(-1) - f
        r[self.fixed_dofs] = 0.0
        return r.reshape(-1, 2)

    def tangent(self, u, *, full: bool = False):
        r"""Tangent stiffness ``K = ∂f_int/∂u`` at ``u``:

        .. math::

            K_{ai,bk} = \sum_e A_e \frac{\partial P_{iJ}}{\partial F_{kL}}
            \nabla N_{aJ} \nabla N_{bL}

        Parameters
        ----------
        u : array_like, shape (N, 2)
            Nodal displacements (``N = mesh.n_nodes``).
        full : bool, optional
            Return the matrix over all DOFs instead of the free ones.

        Returns
        -------
        scipy.sparse matrix
            The reduced ``(n_free, n_free)`` CSC matrix over ``free_dofs`` (default) or,
            with ``full=True``, the ``(2N, 2N)`` CSR matrix over all DOFs (DOF ``2a + i``:
            node ``a``, component ``i``).
        """
        st = self._evaluate_checked(u)
        Ke = self._element_tangents(st)
        if not full:
            return self._pattern.csc(Ke.reshape(-1))
        return self._pattern.full_csr(Ke)

    def _raise_inverted(self, J: np.ndarray, context: str = ""):
        bad = np.flatnonzero(J <= 0.0)
        raise ElementInversionError(
            f"{bad.size} element(s) inverted (det F <= 0){context}: elements {bad[:10].tolist()}, "
            f"min det F = {float(J.min()):.3g}",
            elements=bad,
            min_jacobian=float(J.min()),
        )

    # ---- Newton -------------------------------------------------------------------
    @one_blas_thread
    def solve_with_info(
        self,
        nodal_forces,
        u0=None,
        *,
        fixed_values=None,
        load_steps: int = 1,
        max_halvings: int = 8,
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

        Parameters
        ----------
        nodal_forces : array_like, shape (N, 2)
            Dead external loads ``f_ext`` (their values at fixed nodes are ignored).
        u0 : array_like, shape (N, 2), optional
            Warm start; default the undeformed body.
        fixed_values : array_like, shape (F, 2), optional
            Prescribed displacements of the fixed nodes; default zero.
        load_steps : int, optional
            Equal increments of the load path (>= 1).
        max_halvings : int, optional
            Most halvings of a failed increment per solve.

        Returns
        -------
        u : numpy.ndarray, shape (N, 2)
            The equilibrium, ``‖r_free‖ ≤ rtol · f_ref + atol``.
        info : SolveInfo
            Newton iterations, load steps taken, final residual norm, minimum ``det F``.
        """
        f = as_array(nodal_forces, "nodal_forces", shape=(self.mesh.n_nodes, 2)).reshape(-1).copy()
        f[self.fixed_dofs] = 0.0
        if (
            isinstance(load_steps, bool)
            or not isinstance(load_steps, (int, np.integer))
            or load_steps < 1
        ):
            raise InvalidInputError(f"load_steps: expected an int >= 1, got {load_steps!r}")
        from riskplan.budget import check_budget

        check_budget(
            f"{load_steps} load steps on {self.mesh.n_elements} elements",
            "load_steps",
            seconds=float(load_steps) * (NEWTON_FIXED_S + NEWTON_ELEMENT_S * self.mesh.n_elements),
        )
        if fixed_values is None:
            ub = np.zeros(len(self.fixed_dofs))
        else:
            ub = as_array(fixed_values, "fixed_values", shape=(len(self.fixed_nodes), 2)).reshape(
                -1
            )
        if u0 is None:
            u = np.zeros(self._n)
            cur = self._start(u)
            f0 = np.zeros(self._n)
        else:
            u = self._check_u(u0, "u0")
            cur = self._start(u)
            if cur.energy is None:
                self._raise_inverted(cur.J, " in u0")
            f0 = cur.fint.copy()
            f0[self.fixed_dofs] = 0.0
        ub0 = u[self.fixed_dofs].copy()
        moving = bool(np.any(ub != ub0))
        fscale = max(stable_norm(f[self.free_dofs]), stable_norm(f0[self.free_dofs]))
        if not np.isfinite(fscale):  # finite entries, but the tolerance would overflow
            raise InvalidInputError(
                f"nodal_forces: the load's norm overflows float64 ({fscale}); no equilibrium "
                "can be computed or checked at this scale"
            )
        if moving:
            # forces of the order the prescribed motion produces: linear response to it
            probe = np.zeros(self._n)
            probe[self.fixed_dofs] = ub - ub0
            st = self._evaluate(probe)
            if st.energy is not None:
                fscale = max(fscale, float(np.linalg.norm(st.fint[self.fixed_dofs])))
        if fscale == 0.0:
            fscale = 1.0
        cur, u, rn, iters, steps = load_path(
            self, cur, u, f, f0, ub, ub0, moving, fscale, load_steps, max_halvings
        )
        # a copy: ``u`` may be a cached start's (private) array
        return u.reshape(-1, 2).copy(), SolveInfo(
            iterations=iters, load_steps=steps, residual=rn, min_jacobian=float(cur.J.min())
        )

    def solve(self, nodal_forces, u0=None, *, fixed_values=None, load_steps: int = 1) -> np.ndarray:
        """Equilibrium displacement under dead nodal loads; see :meth:`solve_with_info`.

        Parameters
        ----------
        nodal_forces : array_like, shape (N, 2)
            Dead external loads ``f_ext``.
        u0 : array_like, shape (N, 2), optional
            Warm start; default the undeformed body.
        fixed_values : array_like, shape (F, 2), optional
            Prescribed displacements of the fixed nodes; default zero.
        load_steps : int, optional
            Equal increments of the load path (>= 1).

        Returns
        -------
        numpy.ndarray, shape (N, 2)
        """
        return self.solve_with_info(
            nodal_forces, u0, fixed_values=fixed_values, load_steps=load_steps
        )[0]


class NeoHookeanModel(HyperelasticModel):
    """:class:`HyperelasticModel` with the compressible neo-Hookean law."""

    def __init__(self, mesh: TissueMesh, material: Material, fixed_nodes, **kw):
        super().__init__(mesh, material, fixed_nodes, law="neohookean", **kw)
