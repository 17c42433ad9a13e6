"""LQG-MP in 3-D: the a-priori distributions of the LQG-controlled plan (van den Berg, Abbeel
& Goldberg, IJRR 2011; deformable paper IV-D) checked against 3-D convex obstacles — the
deformed balls and boxes of :mod:`riskplan.scenarios.needle3d`, ellipsoids and
parallelepipeds (:class:`riskplan.geometry3d.ConvexBody`) — with the three methods of the 2-D
:mod:`riskplan.control.lqgmp`:

* ``"sigma"`` (the paper's): ``c_t`` the whitened distance from the mean to the nearest
  obstacle, ``P(free at t) = F_χ²₃(c_t²)`` (the mass inside the ``c_t``-σ ellipsoid of a
  3-D Gaussian; the 2-D code's ``1 − exp(−c²/2)`` is ``F_χ²₂``), ``∏_t``.
* ``"truncation"`` (Patil, van den Berg & Alterovitz, ICRA 2012), in 3-D: per step, the
  obstacles in order of whitened distance; each one not already wholly beyond a chosen
  half-space adds the tangent half-space ``nᵀ y ≤ d`` at its nearest point
  (:func:`riskplan.geometry3d.nearest_to_origin`; convex obstacles need one each, the 2-D
  polygons' edge-by-edge construction is not needed); ``p_t = Σ_j (1 − Φ(d_j))`` and the
  joint Gaussian of ``ξ_t`` is truncated to each half-space in turn
  (``riskplan.control.lqgmp_common._truncate``, moment matching), so later steps see only the
  trajectories that survived; ``P(no collision) = ∏_t (1 − min(1, p_t))``. Obstacles farther
  than ``cutoff`` whitened units are skipped.
* ``"per-step"`` (the estimate Patil 2012 compares the truncation with): the same
  half-spaces and ``p_t`` at every step, without truncating, so the steps count as
  independent.
* ``"sampling"``: ``n_goal_samples`` whole trajectories of the same linear-Gaussian
  recursion, each checked against the deformed obstacles at every step and the target at
  ``T`` — the linear model's own probability (the oracle the two estimates are tested
  against).

``P(goal)``: draws of the final position in the deformed target (after truncation for
``"truncation"``). ``P(success) = P(no collision) · P(goal)``.

**A target that moves with the robot** (``goal_motion=True``, where ``sim`` has
``goal_jacobian(state, params) (3, p)``; off by default): the needle pushes the tissue where its tip is,
so the deformed target's centre is itself a function of the final state, ``c(x_T) ≈
c* + J δx_T``. Success is the tip in the target *as deformed in that execution*, so the
goal test draws the tip's position relative to the moved centre, ``x*_T + (P − J) δx_T``
(``P`` picks the position), against the plan's deformed target (its shape change, second
order, is left out). Off: the target fixed where the plan leaves it. Measured on the 3-D
needle (docs/results.md): the co-motion is real (``J`` matches a regression of the
executions' target centres on their tips), but switched on it made the estimates
optimistic on 4 of 6 plans, because the linear model also under-predicts the tip's final
spread by about as much as the co-motion takes off; off, the two cancel.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr
from scipy.stats import chi2

from riskplan._validation import as_generator, check_count
from riskplan.control.lqgmp_common import (
    METHODS,
    LQGMPResult,
    _check_propagation,
    _closed_loop_draws,
    _factor,
    _truncate,
    joint_covariances,
)
from riskplan.errors import InvalidInputError
from riskplan.geometry3d import nearest_to_origin

__all__ = ["METHODS_3D", "lqgmp_3d"]

#: the 2-D methods and ``"per-step"`` (half-spaces without truncation)
METHODS_3D = (*METHODS, "per-step")

_TINY = 1e-24


def _point_cov(S, p3):
    return S[np.ix_(p3, p3)]


def _check_arguments(plan, controller, n_goal_samples) -> None:
    """Raise :class:`InvalidInputError` unless ``plan`` is a :class:`NominalPlan`,
    ``controller`` its :class:`LQGController` and ``n_goal_samples`` a positive integer."""
    from riskplan.control.lqg import LQGController
    from riskplan.control.plan import NominalPlan

    if not isinstance(plan, NominalPlan):
        raise InvalidInputError(f"plan: expected a NominalPlan, got {type(plan).__name__}")
    if not isinstance(controller, LQGController) or controller.n_steps != plan.n_steps:
        raise InvalidInputError(
            "controller: expected the LQGController of this plan (same number of steps)"
        )
    check_count(n_goal_samples, "n_goal_samples", 1, integral=True)


def lqgmp_3d(
    sim,
    plan,
    controller,
    *,
    method: str = "sigma",
    n_goal_samples: int = 2000,
    cutoff: float | None = None,
    drift: bool = False,
    seed=None,
    goal_motion: bool = False,
) -> LQGMPResult:
    """LQG-MP ``P(success)`` of ``plan`` under ``controller`` against 3-D convex obstacles
    (module docstring). ``sim`` provides ``obstacles(state)`` and ``goal(state)`` as
    :class:`~riskplan.geometry3d.ConvexBody` (``state_obstacles`` / ``state_goal`` in the
    reduced state's coordinates where it has them: the needle's material frame) and ``goal_point_indices`` (3 indices of x, the
    position; also the collision point). Arguments as :func:`riskplan.control.lqgmp.lqgmp`;
    ``goal_motion``: the target moves with the final state where ``sim`` has
    ``goal_jacobian`` (module docstring)."""
    from riskplan.collision import DEFAULT_CUTOFF

    cutoff = DEFAULT_CUTOFF if cutoff is None else float(cutoff)
    if method not in METHODS_3D:
        raise InvalidInputError(f"method: expected one of {METHODS_3D}, got {method!r}")
    _check_arguments(plan, controller, n_goal_samples)
    pos = np.asarray(getattr(sim, "goal_point_indices", (0, 1, 2)), dtype=np.int64)
    if pos.shape != (3,):
        raise InvalidInputError("sim.goal_point_indices: expected the 3 indices of the position")
    T = plan.n_steps
    F, Qn, dm = joint_covariances(controller, drift)
    nz = F.shape[1] // 2
    gen = as_generator(seed)
    mean = np.zeros((T + 1, 2 * nz))
    cov = np.zeros((T + 1, 2 * nz, 2 * nz))
    cov[0, :nz, :nz] = controller.P0
    mu = np.zeros(2 * nz)
    S = cov[0].copy()
    E = _goal_map(sim, plan, pos, 2 * nz, goal_motion)
    if method == "sampling":
        for t in range(T):
            mean[t + 1] = F[t] @ mean[t] + dm[t]
            cov[t + 1] = F[t] @ cov[t] @ F[t].T + Qn[t]
        _check_propagation(mean, cov)
        return _sampled(
            sim, plan, controller, F, Qn, dm, mean, cov, pos, int(n_goal_samples), gen, E
        )
    free = np.ones(T)
    k3 = chi2(3)
    for t in range(T):
        mu = F[t] @ mu + dm[t]
        S = F[t] @ S @ F[t].T + Qn[t]
        S = 0.5 * (S + S.T)
        _check_propagation(mu[None], S[None], t + 1)
        y = plan.states[t + 1]
        bodies = _obstacles(sim, y)
        centre = plan.reduced[t + 1][pos] + mu[pos]
        Sp = _point_cov(S, pos)
        if not bodies:
            mean[t + 1], cov[t + 1] = mu, S
            continue
        if any(bool(b.contains(centre)) for b in bodies):
            free[t] = 0.0
            mean[t + 1], cov[t + 1] = mu, S
            continue
        ev = np.linalg.eigvalsh(Sp)
        if ev[-1] <= _TINY:
            mean[t + 1], cov[t + 1] = mu, S  # a deterministic point outside every obstacle
            continue
        if ev[0] <= 1e-12 * ev[-1]:
            # near-singular (e.g. the force case: the tissue's offset of the tip only scales
            # with f_int, a rank-1 spread): a jitter of 1e-9 of the largest variance, as the
            # 2-D sigma method does; the spread direction keeps its distances
            Sp = Sp + 1e-9 * ev[-1] * np.eye(3)
        L = np.linalg.cholesky(Sp)
        found = [nearest_to_origin(b, L, centre) for b in bodies]
        if method == "sigma":
            c = min(d for d, _ in found)
            free[t] = float(k3.cdf(c * c))
        else:
            order = np.argsort([d for d, _ in found], kind="stable")
            chosen = []  # (n, d) whitened half-spaces
            p_t = 0.0
            for j in order:
                d, n = found[j]
                if d > cutoff:
                    break
                b = bodies[j]
                a = np.linalg.solve(L, b.centre - centre)
                M = np.linalg.solve(L, b.A)
                if any(b.support_min(nc, a, M) >= dc for nc, dc in chosen):
                    continue  # wholly beyond a chosen half-space: its mass is counted there
                chosen.append((n, d))
                p_t += float(ndtr(-d))
            # truncate the joint distribution: nᵀ L⁻¹ (x − centre) ≤ d on the position
            for n, d in chosen if method == "truncation" else ():
                cpos = np.linalg.solve(L.T, n)
                c = np.zeros(2 * nz)
                c[pos] = cpos
                mu, S = _truncate(mu, S, c, d + float(cpos @ mu[pos]))
            free[t] = 1.0 - min(1.0, p_t)
        mean[t + 1], cov[t + 1] = mu, S
    _check_propagation(mean, cov)
    p_free = float(np.prod(free))
    Sx = E @ cov[T] @ E.T
    xT = (
        plan.reduced[T][pos]
        + E @ mean[T]
        + gen.standard_normal((int(n_goal_samples), 3)) @ _factor(0.5 * (Sx + Sx.T)).T
    )
    p_goal = float(_goal(sim, plan.states[T]).contains(xT).mean())
    return LQGMPResult(
        p_success=p_free * p_goal,
        p_collision_free=p_free,
        p_goal=p_goal,
        p_free_steps=free,
        mean=mean,
        cov=cov,
        method=method,
    )


def _obstacles(sim, state):
    """The obstacles in the reduced state's coordinates: ``sim.state_obstacles`` where the
    simulator defines it (the needle's material frame), else ``sim.obstacles``."""
    hook = getattr(sim, "state_obstacles", None)
    return hook(state) if callable(hook) else sim.obstacles(state)


def _goal(sim, state):
    """The target in the reduced state's coordinates (``sim.state_goal`` where defined)."""
    hook = getattr(sim, "state_goal", None)
    return hook(state) if callable(hook) else sim.goal(state)


def _goal_map(sim, plan, pos, n2: int, goal_motion: bool) -> np.ndarray:
    """``E (3, 2n)``: the final tip position relative to the (moving) target centre as a
    function of the joint deviation, ``P − J`` on the state block (module docstring)."""
    E = np.zeros((3, n2))
    E[np.arange(3), pos] = 1.0
    jac = getattr(sim, "goal_jacobian", None) if goal_motion else None
    if jac is not None:
        J = np.asarray(jac(plan.states[-1], plan.params), dtype=np.float64)
        p = plan.reduced.shape[1]
        if J.shape != (3, p) or not np.all(np.isfinite(J)):
            raise InvalidInputError(f"sim.goal_jacobian: expected a finite (3, {p}) matrix")
        E[:, :p] -= J
    return E


def _sampled(sim, plan, controller, F, Qn, dm, mean, cov, pos, n, gen, E) -> LQGMPResult:
    T = plan.n_steps
    alive = np.ones(n, dtype=bool)
    free = np.ones(T)
    for t, xi in _closed_loop_draws(gen, n, T, controller.P0, F, dm, Qn):
        before = int(alive.sum())
        if before == 0:
            free[t] = 0.0
            continue
        x = plan.reduced[t + 1][pos] + xi[:, pos]
        hit = np.zeros(n, dtype=bool)
        for b in _obstacles(sim, plan.states[t + 1]):
            hit |= b.contains(x)
        alive &= ~hit
        free[t] = float(alive.sum()) / before
    xT = plan.reduced[T][pos] + xi @ E.T
    in_goal = _goal(sim, plan.states[T]).contains(xT)
    n_free = int(alive.sum())
    p_goal = float(in_goal[alive].mean()) if n_free else float(in_goal.mean())
    return LQGMPResult(
        p_success=float((alive & in_goal).mean()),
        p_collision_free=n_free / n,
        p_goal=p_goal,
        p_free_steps=free,
        mean=mean,
        cov=cov,
        method="sampling",
    )
