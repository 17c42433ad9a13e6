"""Newton's method for the neo-Hookean law of :class:`~riskplan.deformable.TetTissue`:
full Newton with the consistent tangent, a backtracking line search on the potential
``Π(u) = Σ_e V_e W(F_e) − f·u`` that also rejects steps inverting an element, load stepping
with halving of failed increments, and a linearised predictor for prescribed motion.
Failure raises :class:`~riskplan.errors.ConvergenceError` or
:class:`~riskplan.errors.ElementInversionError`; the tissue's state is only set by the
caller on success.
"""

from __future__ import annotations

import logging

import numpy as np

from riskplan.deformable.hyperelastic import SolveInfo, line_search_failure
from riskplan.deformable.tetassembly import _norm, element_stiffness
from riskplan.deformable.tetfactor import factor_reduced
from riskplan.errors import ConvergenceError, ElementInversionError, InvalidInputError

logger = logging.getLogger(__name__)


def solve_nonlinear(t, f: np.ndarray, ub: np.ndarray, load_steps: int, max_halvings=8):
    u = t._u.copy()
    f0 = t._f.copy()
    ub0 = u[t.fixed_dofs].copy()
    moving = bool(np.any(ub != ub0))
    fscale = max(_norm(f[t.free_dofs]), _norm(f0[t.free_dofs]))
    if not np.isfinite(fscale):
        raise InvalidInputError("nodal_forces: the load's norm overflows float64")
    if moving:  # forces of the order the prescribed motion produces
        probe = np.zeros(t._n)
        probe[t.fixed_dofs] = ub - ub0
        Kfull = t.tangent(u.reshape(-1, 3), full=True)
        fscale = max(fscale, _norm((Kfull @ probe)[t.free_dofs]))
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
                start = _predictor(t, u, target - u[t.fixed_dofs])
            u_new, it, rn, J = _newton(t, start, fs, fscale)
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
        _, _, J, _, _ = t._internal(u)
    t._u, t._f = u, f
    return u.reshape(-1, 3).copy(), SolveInfo(iters, steps, rn, float(np.min(J)))


def _predictor(t, u: np.ndarray, dub: np.ndarray) -> np.ndarray:
    """Fixed DOFs moved by ``dub``, free ones by the linearised response
    ``−K_ff⁻¹ K_fc dub`` (so a prescribed motion does not crush the elements next to
    the supports)."""
    Ke = t._tangent_elements(u)
    Kfull = t._pattern.full_csr(Ke.reshape(-1, 12, 12))
    rhs = Kfull[t.free_dofs][:, t.fixed_dofs] @ dub
    out = u.copy()
    out[t.fixed_dofs] += dub
    out[t.free_dofs] -= factor_reduced(t._pattern, Ke)(rhs)
    return out


def _newton(t, u: np.ndarray, f: np.ndarray, fscale: float):
    """Newton with backtracking on Π from ``u`` for the load ``f`` (flat)."""
    free = t.free_dofs
    energy, fint, J, Finv, lnJ = t._internal(u)
    if energy is None:
        t._raise_inverted(J, " at the start of a load step")
    tol = t.rtol * fscale + t.atol
    f_free = f[free]
    r = fint[free] - f_free
    rn = _norm(r)
    for it in range(t.max_iter + 1):
        if not np.isfinite(rn):
            raise ConvergenceError(
                f"Newton: non-finite residual ({rn}) after {it} iteration(s)",
                residual=rn,
                iterations=it,
            )
        if rn <= tol:
            return u, it, rn, J
        if it == t.max_iter:
            break
        Ke = element_stiffness(t._G, t._V, t._lam, t._mu, Finv, lnJ).reshape(-1)
        try:
            du = -factor_reduced(t._pattern, Ke)(r)
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
            e1, fint1, J1, Finv1, lnJ1 = t._internal(trial)
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
            raise line_search_failure(t._raise_inverted, J_bad, rn, it)
        u, energy, fint, J, Finv, lnJ = trial, e1, fint1, J1, Finv1, lnJ1
        r, rn = r1, rn1
    raise ConvergenceError(
        f"Newton did not converge in {t.max_iter} iterations (residual {rn:.3g}, "
        f"tolerance {tol:.3g})",
        residual=rn,
        iterations=t.max_iter,
    )
