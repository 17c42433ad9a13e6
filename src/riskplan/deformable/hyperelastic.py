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

This module is the solver; the pieces are pure functions elsewhere: element kinematics
(``F``, ``det F``, ``F⁻¹``) in :mod:`.elements`, the laws in :mod:`.laws`, element
forces/tangents and the sparse layouts in :mod:`.assembly`, banded Cholesky in
:mod:`.banded`. Newton's method with a backtracking line search on the total potential energy
``Π(u) = Σ_e A_e W(F_e) − f_ext·u``, that also rejects steps inverting an element
(``det F ≤ 0``), load stepping (adaptive halving) and warm starts.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass

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
from riskplan.deformable.banded import BandedCholeskySolver, cached_layout
from riskplan.deformable.elements import deformation_gradients, determinants_and_inverses
from riskplan.deformable.laws import LAWS, neohookean_energy_and_stress
from riskplan.deformable.material import Material
from riskplan.deformable.mesh import TissueMesh
from riskplan.deformable.nhkernels import (
    LAPACK_BANDWIDTH,
    CompiledBandSolver,
    band_cholesky,
    band_slots,
    neohookean_band,
    neohookean_evaluate,
    scaled_norm,
)
from riskplan.errors import ConvergenceError, ElementInversionError, InvalidInputError
from riskplan.threads import one_blas_thread

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SolveInfo:
    """What a nonlinear solve did: Newton iterations (all load steps), load steps taken,
    final residual norm (free DOFs), minimum ``det F``."""

    iterations: int
    load_steps: int
    residual: float
    min_jacobian: float


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


def _norm(x: np.ndarray) -> float:
    """Euclidean norm that does not overflow for finite entries up to ``1e308`` (scaled by the
    largest magnitude first); ``inf`` or ``nan`` only when an entry is."""
    m = float(np.max(np.abs(x), initial=0.0))  # nan if an entry is
    if m == 0.0 or not np.isfinite(m):
        return m
    return m * float(np.linalg.norm(x / m))


def line_search_failure(raise_inverted, J_bad, residual: float, iterations: int):
    """What a Newton line search that found no acceptable step ends in: ``raise_inverted``
    raises for the inverted elements of its last trial (``J_bad``, ``None`` if none
    inverted), else the :class:`~riskplan.errors.ConvergenceError` returned here is raised."""
    if J_bad is not None:
        raise_inverted(J_bad, " in every line-search trial")
    return ConvergenceError(
        f"Newton line search failed (residual {residual:.3g})",
        residual=residual,
        iterations=iterations,
    )


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
        """``det F`` per element ``(T,)`` for displacements ``u (N, 2)``."""
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
            st.solver = self._new_factor(st)
        return st.solver

    def _new_factor(self, st: _State):
        """Banded Cholesky in the pattern's RCM order, sparse LU when the tangent is not
        positive definite."""
        import scipy.linalg

        pattern = self._pattern
        if self.compiled:
            lapack = pattern.bandwidth > LAPACK_BANDWIDTH
            slots = getattr(pattern, "_nh_slots", None)
            if slots is None:
                slots = pattern._nh_slots = band_slots(pattern, self._tri64.shape[0], lapack)
            ab = np.empty(pattern._band_size)
            neohookean_band(
                st.Finv, st.lnJ, self._Gc, self._areas_c, self._lam, self._mu, slots, ab
            )
            if lapack:  # wide bands: LAPACK's blocked pbtrf, as scipy's cholesky_banded calls it
                (pbtrf,) = scipy.linalg.get_lapack_funcs(("pbtrf",), (ab,))
                cb, info = pbtrf(ab.reshape(pattern.bandwidth + 1, -1), lower=0, overwrite_ab=1)
                if info == 0:
                    return BandedCholeskySolver(cb, pattern.band_perm)
            else:
                cb = ab.reshape(-1, pattern.bandwidth + 1)
                if band_cholesky(cb) == 0:
                    return CompiledBandSolver(cb, pattern.band_perm)
            Ke = self._element_tangents(st).reshape(-1)
            cb = None
        else:
            Ke = self._element_tangents(st).reshape(-1)
            try:
                cb = scipy.linalg.cholesky_banded(
                    pattern.banded(Ke), lower=False, check_finite=False
                )
            except np.linalg.LinAlgError:
                cb = None
        if cb is None:  # not positive definite
            from scipy.sparse.linalg import splu

            try:
                lu = splu(pattern.csc(Ke))
            except RuntimeError as exc:
                raise ConvergenceError(f"Newton: singular tangent ({exc})") from exc
            return lu.solve
        return BandedCholeskySolver(cb, self._pattern.band_perm)

    def _check_u(self, u, name="u") -> np.ndarray:
        return as_array(u, name, shape=(self.mesh.n_nodes, 2)).reshape(-1).copy()

    def _evaluate_checked(self, u) -> _State:
        st = self._evaluate(self._check_u(u))
        if st.energy is None:
            self._raise_inverted(st.J)
        return st

    def energy(self, u) -> float:
        """Stored energy ``Σ_e A_e W(F_e)``; raises :class:`ElementInversionError` if some
        ``det F ≤ 0`` (for both laws: an inverted element is not a physical state).
        """
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
    def _newton(self, st: _State, f: np.ndarray, fscale: float):
        """Newton + backtracking on Π from the evaluated state ``st`` for the load ``f``
        (flat). Returns (state, iterations, residual) or raises."""
        free = self.free_dofs
        if st.energy is None:
            self._raise_inverted(st.J, " at the start of a load step")
        tol = self.rtol * fscale + self.atol
        f_free = f[free]
        r = st.fint[free] - f_free
        norm = scaled_norm if self.compiled else _norm
        rn = norm(r)
        for it in range(self.max_iter + 1):
            if not np.isfinite(rn):
                # an overflowed residual would pass any tolerance test as "not above" only by
                # accident; it is never an equilibrium
                raise ConvergenceError(
                    f"Newton: non-finite residual ({rn}) after {it} iteration(s)",
                    residual=rn,
                    iterations=it,
                )
            if rn <= tol:
                return st, it, rn
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
                rn1 = norm(r1)
                # Armijo on Π, or (near the solution, where Π is flat to round-off)
                # a decrease of the residual norm
                if st1.energy - float(f @ trial) <= pi0 + 1e-4 * alpha * slope or rn1 < 0.5 * rn:
                    break
                alpha *= 0.5
            else:
                raise line_search_failure(self._raise_inverted, J_bad, rn, it)
            st, r, rn = st1, r1, rn1
        raise ConvergenceError(
            f"Newton did not converge in {self.max_iter} iterations (residual {rn:.3g}, tolerance {tol:.3g})",
            residual=rn,
            iterations=self.max_iter,
        )

    def _dirichlet_predictor(self, st: _State, dub: np.ndarray) -> np.ndarray:
        """Move the fixed DOFs by ``dub`` and the free ones by the linearised response
        ``−K_ff⁻¹ K_fc dub`` (tangent at the evaluated state ``st``), so a prescribed
        motion does not crush the elements next to the supports."""
        u = st.u
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
        fscale = max(_norm(f[self.free_dofs]), _norm(f0[self.free_dofs]))
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
        s, ds = 0.0, 1.0 / int(load_steps)
        iters, steps, halvings = 0, 0, 0
        rn = 0.0
        while s < 1.0 - 1e-15:
            s1 = min(1.0, s + ds)
            fs = f if s1 == 1.0 else f0 + s1 * (f - f0)
            try:
                start = cur
                if moving:
                    target = ub if s1 == 1.0 else ub0 + s1 * (ub - ub0)
                    start = self._evaluate(
                        self._dirichlet_predictor(cur, target - u[self.fixed_dofs])
                    )
                st_new, it, rn = self._newton(start, fs, fscale)
            except (ConvergenceError, ElementInversionError) as exc:
                if halvings >= max_halvings:
                    raise exc
                halvings += 1
                ds *= 0.5
                logger.debug("load step %.3g -> %.3g failed (%s); halving", s, s1, exc)
                continue
            iters += it
            steps += 1
            cur, u, s = st_new, st_new.u, s1
            if it <= 4:  # an easy increment: let the next one grow back towards 1/load_steps
                ds = min(2.0 * ds, 1.0 / int(load_steps))
        if not (np.isfinite(rn) and np.all(np.isfinite(u))):  # never hand back a silent failure
            raise ConvergenceError(
                f"nonlinear solve ended on a non-finite state (residual {rn})",
                residual=rn,
                iterations=iters,
            )
        # a copy: ``u`` may be a cached start's (private) array
        return u.reshape(-1, 2).copy(), SolveInfo(
            iterations=iters, load_steps=steps, residual=rn, min_jacobian=float(cur.J.min())
        )

    def solve(self, nodal_forces, u0=None, *, fixed_values=None, load_steps: int = 1) -> np.ndarray:
        """Equilibrium displacement ``(N, 2)``; see :meth:`solve_with_info`."""
        return self.solve_with_info(
            nodal_forces, u0, fixed_values=fixed_values, load_steps=load_steps
        )[0]


class NeoHookeanModel(HyperelasticModel):
    """:class:`HyperelasticModel` with the compressible neo-Hookean law."""

    def __init__(self, mesh: TissueMesh, material: Material, fixed_nodes, **kw):
        super().__init__(mesh, material, fixed_nodes, law="neohookean", **kw)
