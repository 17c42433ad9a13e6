r"""Newton's method of the 2-D hyperelastic model (:mod:`riskplan.deformable.hyperelastic`):
the factorised reduced tangent (banded Cholesky in the layout's RCM order, sparse LU when the
tangent is not positive definite), Newton with a backtracking line search on the total
potential energy

.. math::

    \Pi(u) = \sum_e A_e W(F_e) - f_{\mathrm{ext}} \cdot u

that also rejects steps inverting an element (``det F ≤ 0``), the linearised predictor of a
prescribed-displacement increment, and load stepping with adaptive halving.

The functions take the model (a :class:`~riskplan.deformable.HyperelasticModel`) as their
first argument and read its evaluations (``_evaluate``, ``_factor``); :class:`SolveInfo`
reports what a solve did.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from riskplan.deformable.banded import BandedCholeskySolver
from riskplan.deformable.nhkernels import (
    LAPACK_BANDWIDTH,
    CompiledBandSolver,
    band_cholesky,
    band_slots,
    neohookean_band,
    scaled_norm,
)
from riskplan.errors import ConvergenceError, ElementInversionError

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SolveInfo:
    """What a nonlinear solve did: Newton iterations (all load steps), load steps taken,
    final residual norm (free DOFs), minimum ``det F``."""

    iterations: int
    load_steps: int
    residual: float
    min_jacobian: float


def stable_norm(x: np.ndarray) -> float:
    """Euclidean norm that does not overflow for finite entries up to ``1e308`` (scaled by the
    largest magnitude first); ``inf`` or ``nan`` only when an entry is."""
    m = float(np.max(np.abs(x), initial=0.0))  # nan if an entry is
    if m == 0.0 or not np.isfinite(m):
        return m
    return m * float(np.linalg.norm(x / m))


def line_search_failure(raise_inverted, J_bad, residual: float, iterations: int):
    """What a Newton line search that found no acceptable step ends in: ``raise_inverted``
    raises for the inverted elements of its last trial (``J_bad``, ``None`` if none
    inverted), else the :class:`~riskplan.errors.ConvergenceError` returned here is raised.

    Parameters
    ----------
    raise_inverted : callable
        ``raise_inverted(J_bad, context)`` raises for inverted elements.
    J_bad : numpy.ndarray or None
        ``(E,)`` det F per element of the last trial (some <= 0), or None.
    residual : float
        The last residual norm.
    iterations : int
        Newton iterations run.

    Returns
    -------
    ConvergenceError
        The error to raise.
    """
    if J_bad is not None:
        raise_inverted(J_bad, " in every line-search trial")
    return ConvergenceError(
        f"Newton line search failed (residual {residual:.3g})",
        residual=residual,
        iterations=iterations,
    )


def factor_tangent(model, st):
    """Banded Cholesky in the pattern's RCM order, sparse LU when the tangent is not
    positive definite."""
    import scipy.linalg

    pattern = model._pattern
    if model.compiled:
        lapack = pattern.bandwidth > LAPACK_BANDWIDTH
        slots = getattr(pattern, "_nh_slots", None)
        if slots is None:
            slots = pattern._nh_slots = band_slots(pattern, model._tri64.shape[0], lapack)
        ab = np.empty(pattern._band_size)
        neohookean_band(
            st.Finv, st.lnJ, model._Gc, model._areas_c, model._lam, model._mu, slots, ab
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
        Ke = model._element_tangents(st).reshape(-1)
        cb = None
    else:
        Ke = model._element_tangents(st).reshape(-1)
        try:
            cb = scipy.linalg.cholesky_banded(pattern.banded(Ke), lower=False, check_finite=False)
        except np.linalg.LinAlgError:
            cb = None
    if cb is None:  # not positive definite
        from scipy.sparse.linalg import splu

        try:
            lu = splu(pattern.csc(Ke))
        except RuntimeError as exc:
            raise ConvergenceError(f"Newton: singular tangent ({exc})") from exc
        return lu.solve
    return BandedCholeskySolver(cb, model._pattern.band_perm)


def newton(model, st, f: np.ndarray, fscale: float):
    """Newton + backtracking on Π from the evaluated state ``st`` for the load ``f``
    (flat). Returns (state, iterations, residual) or raises."""
    free = model.free_dofs
    if st.energy is None:
        model._raise_inverted(st.J, " at the start of a load step")
    tol = model.rtol * fscale + model.atol
    f_free = f[free]
    r = st.fint[free] - f_free
    norm = scaled_norm if model.compiled else stable_norm
    rn = norm(r)
    for it in range(model.max_iter + 1):
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
        if it == model.max_iter:
            break
        try:
            du = -model._factor(st)(r)
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
            st1 = model._evaluate(trial)
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
            raise line_search_failure(model._raise_inverted, J_bad, rn, it)
        st, r, rn = st1, r1, rn1
    raise ConvergenceError(
        f"Newton did not converge in {model.max_iter} iterations (residual {rn:.3g}, tolerance {tol:.3g})",
        residual=rn,
        iterations=model.max_iter,
    )


def dirichlet_predictor(model, st, dub: np.ndarray) -> np.ndarray:
    """Move the fixed DOFs by ``dub`` and the free ones by the linearised response
    ``−K_ff⁻¹ K_fc dub`` (tangent at the evaluated state ``st``), so a prescribed
    motion does not crush the elements next to the supports."""
    u = st.u
    if st.energy is None:
        model._raise_inverted(st.J, " before a prescribed-displacement increment")
    Kfull = model.tangent(u.reshape(-1, 2), full=True)
    rhs = Kfull[model.free_dofs][:, model.fixed_dofs] @ dub
    out = u.copy()
    out[model.fixed_dofs] += dub
    out[model.free_dofs] -= model._factor(st)(rhs)
    return out


def load_path(model, cur, u, f, f0, ub, ub0, moving: bool, fscale: float, load_steps, max_halvings):
    """Load stepping of :meth:`HyperelasticModel.solve_with_info` from the evaluated start
    ``cur`` (flat displacement ``u``): the load from ``f0`` to ``f`` and, when ``moving``,
    the fixed DOFs from ``ub0`` to ``ub``, in ``load_steps`` equal increments, each solved by
    :func:`newton`; a failed increment is halved (at most ``max_halvings`` times per solve)
    and grows back after increments that converge in at most 4 iterations.

    Returns ``(state, u, residual, iterations, load steps taken)``; raises what the last
    failed increment raised, or :class:`~riskplan.errors.ConvergenceError` on a non-finite
    end state."""
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
                start = model._evaluate(
                    dirichlet_predictor(model, cur, target - u[model.fixed_dofs])
                )
            st_new, it, rn = newton(model, start, fs, fscale)
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
    return cur, u, rn, iters, steps
