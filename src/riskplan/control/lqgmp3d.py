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

``P(goal)``: the probability that the final position (after truncation for
``"truncation"``) lies in the deformed target — exactly, by quadrature, for an ellipsoid
(:mod:`riskplan.control.lqgmp3d_goal`; every target of the 3-D needle is one), else by draws
(``goal="draws"`` selects them for any target). ``P(success) = P(no collision) · P(goal)``.

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

**Beyond the linear model** (``moments=``, a
:class:`~riskplan.control.lqgmp3d_moments.SecondOrderModel`): every method runs on that
model's recursion instead, the checked position ``x*_{t+1} + offset_t + P_t ξ + ε_t`` with a
residual ``ε_t`` of its own (truncated jointly with ``ξ``, then dropped), and the goal test on
the tip relative to the moving target that the model carries (its spread now right, the
co-motion belongs in it).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import chdtr, ndtr

from riskplan._validation import as_generator, check_count
from riskplan.control.lqgmp3d_goal import gaussian_in_ellipsoid
from riskplan.control.lqgmp3d_moments import SecondOrderModel
from riskplan.control.lqgmp_common import (
    METHODS,
    LQGMPResult,
    _check_propagation,
    _factor,
    _truncate,
    joint_covariances,
)
from riskplan.errors import InvalidInputError
from riskplan.geometry3d import nearest_to_origin

__all__ = ["GOAL_TESTS", "METHODS_3D", "binomial_se", "lqgmp_3d"]

#: the 2-D methods and ``"per-step"`` (half-spaces without truncation)
METHODS_3D = (*METHODS, "per-step")

#: goal tests of :func:`lqgmp_3d`: the exact probability (quadrature) and the draws
GOAL_TESTS = ("exact", "draws")

_TINY = 1e-24


def _check_arguments(
    plan, controller, n_goal_samples, method=None, goal_se=None, max_goal_samples=1, goal="exact"
) -> None:
    """Raise :class:`InvalidInputError` unless ``method`` is one of :data:`METHODS_3D` (or
    ``None``), ``goal`` one of ``GOAL_TESTS``, ``plan`` a :class:`NominalPlan`,
    ``controller`` its :class:`LQGController`, ``n_goal_samples`` a positive integer and
    ``goal_se`` ``None`` or (not for ``"sampling"``) a finite number > 0 with
    ``max_goal_samples`` a positive integer."""
    from riskplan.control.lqg import LQGController
    from riskplan.control.plan import NominalPlan

    if method is not None and method not in METHODS_3D:
        raise InvalidInputError(f"method: expected one of {METHODS_3D}, got {method!r}")
    if goal not in GOAL_TESTS:
        raise InvalidInputError(f"goal: expected one of {GOAL_TESTS}, got {goal!r}")
    if not isinstance(plan, NominalPlan):
        raise InvalidInputError(f"plan: expected a NominalPlan, got {type(plan).__name__}")
    if not isinstance(controller, LQGController) or controller.n_steps != plan.n_steps:
        raise InvalidInputError(
            "controller: expected the LQGController of this plan (same number of steps)"
        )
    check_count(n_goal_samples, "n_goal_samples", 1, integral=True)
    if goal_se is not None:
        if method == "sampling":
            raise InvalidInputError("goal_se: not for method='sampling' (use n_goal_samples)")
        if not (isinstance(goal_se, (int, float)) and math.isfinite(goal_se) and goal_se > 0):
            raise InvalidInputError(f"goal_se: expected a finite number > 0, got {goal_se!r}")
        check_count(max_goal_samples, "max_goal_samples", 1, integral=True)


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
    moments=None,
    goal_se: float | None = None,
    max_goal_samples: int = 1_000_000,
    goal: str = "exact",
) -> LQGMPResult:
    """LQG-MP ``P(success)`` of ``plan`` under ``controller`` against 3-D convex obstacles
    (module docstring).

    Parameters
    ----------
    sim : Simulator
        ``obstacles(state)`` and ``goal(state)`` as :class:`~riskplan.geometry3d.ConvexBody`
        (``state_obstacles`` / ``state_goal`` in the reduced state's coordinates where it has
        them: the needle's material frame) and ``goal_point_indices`` (3 indices of x, the
        position; also the collision point).
    plan, controller, method, n_goal_samples, cutoff, drift, seed
        As :func:`riskplan.control.lqgmp.lqgmp`.
    goal_motion : bool
        The target moves with the final state where ``sim`` has ``goal_jacobian``.
    moments : SecondOrderModel, optional
        A :class:`~riskplan.control.lqgmp3d_moments.SecondOrderModel` of this plan and
        controller to run the methods on instead of the linear model (``drift`` and
        ``goal_motion`` then do not apply: the model carries its own mean and moving target).
    goal_se : float, optional
        The goal test's precision instead of a count (not for ``"sampling"``, whose draws are
        whole trajectories): batches of ``n_goal_samples`` final positions are drawn until
        ``sqrt(p̃(1 − p̃)/n) <= goal_se`` or ``n >= max_goal_samples``, with
        ``p̃ = (k + 1)/(n + 2)`` for ``k`` of ``n`` draws in the target (the Laplace estimate,
        so a first batch with no miss does not read as a standard error of 0). The estimate
        stays ``k/n``.
    max_goal_samples : int
        Most goal draws with ``goal_se``.
    goal : {"exact", "draws"}
        Not for ``"sampling"`` (its trajectories are its goal test). ``"exact"``: the
        probability of the final position's Gaussian in the target by quadrature
        (:func:`~riskplan.control.lqgmp3d_goal.gaussian_in_ellipsoid`) where the target is an
        ellipsoid (every target of the 3-D needle), with ``n_goal_samples`` 0 and
        ``p_success_se`` ``p_free`` times its error bound; another target, or ``"draws"``,
        takes the draws of ``goal_se``.

    Returns
    -------
    LQGMPResult
        ``p_success`` and its factors per step, the distributions, ``n_goal_samples``,
        ``p_success_se`` and ``goal_test`` (which test ran).
    """
    from riskplan.collision import DEFAULT_CUTOFF

    cutoff = DEFAULT_CUTOFF if cutoff is None else float(cutoff)
    _check_arguments(plan, controller, n_goal_samples, method, goal_se, max_goal_samples, goal)
    pos = np.asarray(getattr(sim, "goal_point_indices", (0, 1, 2)), dtype=np.int64)
    if pos.shape != (3,):
        raise InvalidInputError("sim.goal_point_indices: expected the 3 indices of the position")
    T = plan.n_steps
    model = _model(sim, plan, controller, pos, drift, goal_motion, moments)
    gen = as_generator(seed)
    if method == "sampling":
        return _sampled(sim, plan, model, pos, int(n_goal_samples), gen)
    n2 = model.F.shape[1]
    mean = np.zeros((T + 1, n2))
    cov = np.zeros((T + 1, n2, n2))
    cov[0] = model.P0
    mu = np.zeros(n2)
    S = cov[0].copy()
    free = np.ones(T)
    for t in range(T):
        mu = model.F[t] @ mu + model.c[t]
        S = model.F[t] @ S @ model.F[t].T + model.Q[t]
        S = 0.5 * (S + S.T)
        _check_propagation(mu[None], S[None], t + 1)
        free[t], mu, S = _step_free(sim, plan, model, pos, method, cutoff, t, mu, S)
        mean[t + 1], cov[t + 1] = mu, S
    _check_propagation(mean, cov)
    p_free = float(np.prod(free))
    Sx = model.goal_P @ cov[T] @ model.goal_P.T + model.goal_resid
    centre = plan.reduced[T][pos] + model.goal_offset + model.goal_P @ mean[T]
    draws = (int(n_goal_samples), goal_se, int(max_goal_samples), gen)
    p_goal, n, err, used = _goal_test(
        _goal(sim, plan.states[T]), centre, 0.5 * (Sx + Sx.T), goal, draws
    )
    return LQGMPResult(
        p_success=p_free * p_goal,
        p_collision_free=p_free,
        p_goal=p_goal,
        p_free_steps=free,
        mean=mean,
        cov=cov,
        method=method,
        n_goal_samples=n,
        p_success_se=p_free * err,
        goal_test=used,
    )


def _step_free(sim, plan, model, pos, method, cutoff, t, mu, S):
    """The factor ``P(free at step t + 1)`` of :func:`lqgmp_3d` and the joint moments after it
    (truncated with ``"truncation"``)."""
    y = plan.states[t + 1]
    bodies = _obstacles(sim, y)
    P, R = model.P[t], model.resid[t]
    centre = plan.reduced[t + 1][pos] + model.offset[t] + P @ mu
    Sp = P @ S @ P.T + R
    if not bodies:
        return 1.0, mu, S
    if any(bool(b.contains(centre)) for b in bodies):
        return 0.0, mu, S
    ev = np.linalg.eigvalsh(Sp)
    if ev[-1] <= _TINY:
        return 1.0, mu, S  # a deterministic point outside every obstacle
    if ev[0] <= 1e-12 * ev[-1]:
        # near-singular (e.g. the force case: the tissue's offset of the tip only scales
        # with f_int, a rank-1 spread): a jitter of 1e-9 of the largest variance, as the
        # 2-D sigma method does; the spread direction keeps its distances
        Sp = Sp + 1e-9 * ev[-1] * np.eye(3)
    L = np.linalg.cholesky(Sp)
    found = _nearest(bodies, L, centre, None if method == "sigma" else cutoff)
    if method == "sigma":
        c = min(d for d, _ in found)
        # the χ²₃ CDF (scipy.stats' chi2(3).cdf; a frozen distribution per step costs 1 ms)
        return float(chdtr(3, c * c)), mu, S
    chosen = _half_spaces(bodies, found, L, centre, cutoff)
    p_t = sum(float(ndtr(-d)) for _, d in chosen)
    if method == "truncation" and chosen:
        mu, S = _truncate_step(mu, S, P, R, model.cross[t], L, chosen)
    return 1.0 - min(1.0, p_t), mu, S


def binomial_se(k: int, n: int) -> float:
    """Standard error of a fraction of independent draws.

    Parameters
    ----------
    k : int
        Draws that hit (``0 <= k <= n``).
    n : int
        Draws (``>= 1``).

    Returns
    -------
    float
        ``sqrt(p̃(1 − p̃)/n)`` with the Laplace estimate ``p̃ = (k + 1)/(n + 2)`` (never 0
        for ``k = 0`` or ``k = n``, where ``k/n`` would read as exact).
    """
    pt = (k + 1.0) / (n + 2.0)
    return float(np.sqrt(pt * (1.0 - pt) / n))


def draw_until(run_batch, batch: int, p_se: float | None, max_n: int):
    """Batches of Monte Carlo draws until the binomial standard error of the hit fraction is
    at most ``p_se``.

    Parameters
    ----------
    run_batch : callable
        ``run_batch(m) -> (k, extra)``: ``k`` hits among ``m`` new independent draws, and
        whatever else the batch returns.
    batch : int
        Draws per batch (the last one cut to ``max_n``).
    p_se : float or None
        Target standard error :func:`~riskplan.control.lqgmp3d.binomial_se` ``(k, n)``;
        ``None``: one batch of ``max_n``.
    max_n : int
        Cap on the draws.

    Returns
    -------
    tuple
        ``(k, n, extras)``: hits, draws and the batches' ``extra`` in order. Stops after the
        first batch at which ``binomial_se(k, n) <= p_se`` or ``n = max_n``.
    """
    k = n = 0
    extras = []
    while True:
        m = max_n if p_se is None else min(batch, max_n - n)
        hits, extra = run_batch(m)
        k, n = k + int(hits), n + m
        extras.append(extra)
        if p_se is None or n >= max_n or binomial_se(k, n) <= p_se:
            return k, n, extras


def _goal_test(body, centre, Sx, goal: str, draws) -> tuple[float, int, float, str]:
    """``(P(goal), n, err, used)`` of the final position ``N(centre, Sx)`` in ``body``:
    ``"exact"`` on an ellipsoid by :func:`~riskplan.control.lqgmp3d_goal.gaussian_in_ellipsoid`
    (``n = 0``, ``err`` its error bound), else ``draws = (batch, goal_se, max_n, gen)`` by
    ``_goal_draws`` (``n`` the draws, ``err`` :func:`binomial_se`)."""
    if goal == "exact" and body.kind == "ellipsoid":
        # the nearest positive semi-definite matrix, as the draws' eigen-factor takes it: a
        # residual covariance of the statistical linearisation can be indefinite by round-off
        w, V = np.linalg.eigh(Sx)
        p, err = gaussian_in_ellipsoid(body, centre, (V * np.clip(w, 0.0, None)) @ V.T)
        return p, 0, err, "exact"
    batch, goal_se, max_n, gen = draws
    k, n = _goal_draws(body, centre, _factor(Sx), batch, goal_se, max_n, gen)
    return k / n, n, binomial_se(k, n), "draws"


def _goal_draws(body, centre, L, batch, goal_se, max_n, gen) -> tuple[int, int]:
    """``(k, n)``: ``k`` of ``n`` draws ``centre + L z`` (``z ~ N(0, I_3)``) inside ``body``.
    ``n = batch`` without ``goal_se``; with it, batches until :func:`binomial_se` is at most
    ``goal_se`` or ``n`` reaches ``max_n`` (the last batch cut to it)."""

    def run_batch(m):
        return np.count_nonzero(body.contains(centre + gen.standard_normal((m, 3)) @ L.T)), None

    k, n, _ = draw_until(run_batch, batch, goal_se, batch if goal_se is None else max_n)
    return k, n


def _nearest(bodies, L, centre, cutoff) -> list:
    """``nearest_to_origin`` of each body in the whitened frame; with a ``cutoff``, a body
    whose lower bound ``‖L⁻¹(c − centre)‖ − ‖L⁻¹A‖_F r`` (``r = 1`` for an ellipsoid, ``√3``
    for a box: the largest ``|s|`` of its unit set) already exceeds it gets ``(inf, None)``
    without the search (the half-spaces stop at the cutoff)."""
    out = []
    for b in bodies:
        if cutoff is not None:
            a = np.linalg.norm(np.linalg.solve(L, b.centre - centre))
            r = 1.0 if b.kind == "ellipsoid" else math.sqrt(3.0)
            if a - np.linalg.norm(np.linalg.solve(L, b.A)) * r > cutoff:
                out.append((math.inf, None))
                continue
        out.append(nearest_to_origin(b, L, centre))
    return out


def _half_spaces(bodies, found, L, centre, cutoff) -> list:
    """Patil 2012's half-spaces of one step: ``(n, d)`` whitened, nearest obstacle first,
    skipping an obstacle wholly beyond a chosen half-space (its mass is counted there) and
    those farther than ``cutoff``."""
    order = np.argsort([d for d, _ in found], kind="stable")
    chosen = []
    for j in order:
        d, n = found[j]
        if d > cutoff:
            break
        b = bodies[j]
        a = np.linalg.solve(L, b.centre - centre)
        M = np.linalg.solve(L, b.A)
        if any(b.support_min(nc, a, M) >= dc for nc, dc in chosen):
            continue
        chosen.append((n, d))
    return chosen


def _truncate_step(mu, S, P, R, cross, L, chosen):
    """Truncate ``N(mu, S)`` of ``ξ`` by the step's half-spaces ``nᵀ L⁻¹ (y − centre) ≤ d`` on
    the position ``y = centre + P (ξ − mu) + ε`` (``ε ~ N(0, R)``, ``Cov(ξ, ε) = cross``): the
    joint Gaussian of ``(ξ, ε)`` is truncated to each half-space in turn and ``ε``, this
    step's alone, is dropped after. The planes stay where the step's centre put them."""
    n2 = mu.shape[0]
    m = np.concatenate([mu, np.zeros(3)])
    C = np.block([[S, cross], [cross.T, R]])
    start = P @ mu
    for n, d in chosen:
        cpos = np.linalg.solve(L.T, n)
        c = np.concatenate([P.T @ cpos, cpos])
        m, C = _truncate(m, C, c, d + float(cpos @ start))
    return m[:n2], C[:n2, :n2]


def _model(sim, plan, controller, pos, drift, goal_motion, moments):
    """The recursion the methods run on: ``moments`` (checked against the plan), else the
    linear model of ``controller`` (:func:`joint_covariances`)."""
    T = plan.n_steps
    if moments is not None:
        if not isinstance(moments, SecondOrderModel) or moments.n_steps != T:
            raise InvalidInputError(
                "moments: expected the SecondOrderModel of this plan (same number of steps)"
            )
        if moments.F.shape[1] != 2 * controller.model()[0].shape[1]:
            raise InvalidInputError("moments: built for another controller's state dimension")
        return moments
    F, Qn, dm = joint_covariances(controller, drift)
    n2 = F.shape[1]
    nz = n2 // 2
    P = np.zeros((3, n2))
    P[np.arange(3), pos] = 1.0
    P0 = np.zeros((n2, n2))
    P0[:nz, :nz] = controller.P0
    # the linear model in the second-order model's form: no offsets, no residual, the
    # position is P ξ
    return SecondOrderModel(
        F=F,
        c=dm,
        Q=Qn,
        P=np.broadcast_to(P, (T, 3, n2)),
        offset=np.zeros((T, 3)),
        resid=np.zeros((T, 3, 3)),
        cross=np.zeros((T, n2, 3)),
        goal_P=_goal_map(sim, plan, pos, n2, goal_motion),
        goal_offset=np.zeros(3),
        goal_resid=np.zeros((3, 3)),
        P0=P0,
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


def _sampled(sim, plan, model, pos, n, gen) -> LQGMPResult:
    """``method="sampling"``: ``n`` trajectories of the model's recursion, each position
    ``x*_{t+1}[pos] + offset_t + P_t ξ + ε_t`` checked against the obstacles at every step,
    the final one (relative to the moving target with ``moments``) against the target."""
    T = plan.n_steps
    n2 = model.F.shape[1]
    mean = np.zeros((T + 1, n2))
    cov = np.zeros((T + 1, n2, n2))
    cov[0] = model.P0
    xi = gen.standard_normal((n, n2)) @ _factor(model.P0).T
    alive = np.ones(n, dtype=bool)
    free = np.ones(T)
    for t in range(T):
        mean[t + 1] = model.F[t] @ mean[t] + model.c[t]
        cov[t + 1] = model.F[t] @ cov[t] @ model.F[t].T + model.Q[t]
        # ε_t and the part of the step's noise it explains (the filter saw it), then the rest
        R, X = model.resid[t], model.cross[t]
        Rp = np.linalg.pinv(R, hermitian=True) if R.any() else np.zeros((3, 3))
        eps = gen.standard_normal((n, 3)) @ _factor(R).T
        rest = model.Q[t] - X @ Rp @ X.T
        xi = xi @ model.F[t].T + model.c[t] + eps @ (X @ Rp).T
        xi += gen.standard_normal((n, n2)) @ _factor(0.5 * (rest + rest.T)).T
        before = int(alive.sum())
        if before == 0:
            free[t] = 0.0
            continue
        x = plan.reduced[t + 1][pos] + model.offset[t] + xi @ model.P[t].T + eps
        hit = np.zeros(n, dtype=bool)
        for b in _obstacles(sim, plan.states[t + 1]):
            hit |= b.contains(x)
        alive &= ~hit
        free[t] = float(alive.sum()) / before
    _check_propagation(mean, cov)
    eps = gen.standard_normal((n, 3)) @ _factor(model.goal_resid).T
    xT = plan.reduced[T][pos] + model.goal_offset + xi @ model.goal_P.T + eps
    in_goal = _goal(sim, plan.states[T]).contains(xT)
    n_free = int(alive.sum())
    p_goal = float(in_goal[alive].mean()) if n_free else float(in_goal.mean())
    k = int(np.count_nonzero(alive & in_goal))
    return LQGMPResult(
        p_success=k / n,
        p_collision_free=n_free / n,
        p_goal=p_goal,
        p_free_steps=free,
        mean=mean,
        cov=cov,
        method="sampling",
        n_goal_samples=n,
        p_success_se=binomial_se(k, n),
    )
