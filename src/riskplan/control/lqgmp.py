"""LQG-MP: a-priori distributions of the LQG-controlled plan and its probability of success
(deformable-planning paper, Patil, van den Berg & Alterovitz, RSS 2011, section IV-D;
van den Berg, Abbeel & Goldberg, "LQG-MP", IJRR 2011, section V; Patil, van den Berg &
Alterovitz, ICRA 2012 for the truncation variant).

Joint deviation ``ξ_t = (x̄_t, x̂_t)`` (true and estimated), with the indexing of
:mod:`riskplan.control.kalman` (``H_t``, ``K_t`` belong to the measurement after step t).
Substituting ``ū_t = L_t x̂_t`` into the model and the filter:

    x̄_{t+1} = A_t x̄_t + B_t L_t x̂_t + m_t
    x̂_{t+1} = K_t H_t A_t x̄_t + (A_t + B_t L_t − K_t H_t A_t) x̂_t + K_t H_t m_t + K_t n_t

so ``ξ_{t+1} = F_t ξ_t + G_t (m_t, n_t)`` with

    F_t = [[A_t, B_t L_t], [K_t H_t A_t, A_t + B_t L_t − K_t H_t A_t]],   G_t = [[I, 0], [K_t H_t, K_t]]

and ``Σ_{t+1} = F_t Σ_t F_tᵀ + G_t diag(M_t, N_t) G_tᵀ``, ``Σ_0 = diag(P0, 0)`` (the estimate
starts at the plan). Control clipping is ignored (a linear model).

The true state at ``t`` is ``x_t ~ N(x*_t + μ_t[:p], Σ_t[:p, :p])``. Collision is checked for
the 2-D points of ``x`` named by :func:`point_indices` (or, when the simulator declares
``collision_outline``, for the body's closed outline whose vertices move with interpolated
deviations of those points, :func:`body_points`: vertices plus :data:`OUTLINE_POINTS`
points inside each edge for sigma and truncation, a mean outline meeting an obstacle
giving 0; vertices and edges of every sampled outline for sampling) against the *deformed* obstacles of
the plan's stored state ``y*_t`` (``sim.obstacles(y*_t)``), with the 2-D collision API
(:func:`riskplan.collision.free_region`, the Patil 2012 construction):

* ``method="sigma"`` (the paper's choice, from LQG-MP and the LQGMPManipulator reference
  code): ``c_t`` = the number of standard deviations from the mean to the nearest obstacle
  (Mahalanobis distance, the first half-space of the construction, minimum over the
  points); ``P(free at t) = F_χ²₂(c_t²) = 1 − exp(−c_t²/2)``; ``P(no collision) = ∏_t``.
  Zero if a mean is inside an obstacle.
* ``method="truncation"`` (Patil et al. ICRA 2012): per step and point, the half-spaces
  ``a_j·x ≤ b_j`` of the free region; ``p_t = Σ_j (1 − Φ(α_j))`` (α_j the whitened
  distances); the joint Gaussian of ``ξ_t`` is then truncated to each half-space in turn
  (moments of a truncated normal, conditioned linearly), so later steps see only the
  trajectories that survived; ``P(no collision) = ∏_t (1 − min(1, p_t))``.
* ``method="sampling"`` (beyond the papers): ``n_goal_samples`` whole trajectories
  ``ξ_0 .. ξ_T`` drawn from the same linear-Gaussian recursion (so the steps keep their
  correlation), each checked against the deformed obstacles at every step and against the
  goal at ``T``; ``P(success)`` is the fraction that does both. This is the probability of
  the linearised model itself, with a binomial sampling error (at most ``0.5/√n``) and no
  approximation beyond the linear model.

The sigma estimate is conservative by construction, and far below the linear model's own
probability when a plan passes within a few standard deviations of an obstacle: the
χ²₂ factor counts the mass outside the whole ``c_t``-σ ellipse, as if every direction led
into an obstacle, where the mass inside one convex obstacle is at most ``1 − Φ(c_t)``
(beyond the tangent at its nearest point; ``c_t = 0.5``: 0.88 against ≤ 0.31); and
multiplying the factors treats strongly correlated steps as independent. On an RRT needle plan (docs/planning.md,
"rank 20") sigma gave 0.097, the linear model sampled 0.746, and closed-loop executions on
the true simulator 0.739–0.755. Use ``"truncation"`` or ``"sampling"`` where the number
itself matters rather than the ranking.

Beyond the paper, ``drift=True`` carries the mean ``d̄_t`` of the one-step deviations under S
(:attr:`Linearization.drift`): ``μ_{t+1} = F_t μ_t + G_t (d̄_t, 0)``, process covariance
``M_t − d̄_t d̄_tᵀ``. The paper's zero-mean model misses systematic shifts, e.g. actuation
noise clipped at a control bound (a needle planned at ``v_max`` lags on average).

Beyond the paper, a controller with the persistent-disturbance state
(``lqg_controller(lin, disturbance=True)``) propagates the same recursion on its augmented
model (:func:`riskplan.control.lqg.augmented_model`): ``ξ_t = (x̄_t, d, x̂_t, d̂_t)`` of
dimension ``2(p + q)``, ``A_t, B_t, H_t, M_t`` replaced by the augmented ones, ``L_t`` by
``[L_t, −I]`` and ``Σ_0 = diag(P0, Σ_d, 0, 0)``: the true ``d ~ N(0, Σ_d)`` is drawn once and
kept, the estimate starts at zero. With a persistent measurement bias ``e`` in the model
(:func:`riskplan.control.linearize.fit_measurement_bias`) ``e`` joins ``d`` the same way
(dimension ``2(p + q + r)``).

Obstacles and goal are read in the reduced state's coordinates: ``sim.state_obstacles`` /
``sim.state_goal`` where the simulator defines them (the needle's material frame: the
reference polygons), else ``sim.obstacles`` / ``sim.goal``. Collision and goal are read from ``x̄_t = ξ_t[:p]`` as
before; every method (sigma, truncation, sampling) works unchanged on it.

``P(goal)``: ``n_goal_samples`` draws of ``x_T`` (the final, truncated distribution in the
truncation variant), counting those whose goal point lies in the deformed goal polygon
``sim.goal(y*_T)``. ``P(success) = P(no collision) · P(goal)`` (paper IV-D).
With ``"sampling"``, ``P(goal)`` is the fraction of the collision-free trajectories that
end in the goal (of all of them if none is free), so the product is still ``P(success)``,
and ``p_free_steps[t]`` is the fraction of the trajectories free up to step ``t`` that are
free at ``t + 1``.
"""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_generator
from riskplan.control.lqg import LQGController
from riskplan.control.lqgmp3d import _check_arguments, lqgmp_3d
from riskplan.control.lqgmp_common import (
    METHODS,
    LQGMPResult,
    _check_propagation,
    _closed_loop_draws,
    _mix,
    _sigma_step,
    _truncation_step,
    joint_covariances,
)
from riskplan.control.plan import NominalPlan
from riskplan.errors import InvalidInputError

__all__ = [
    "METHODS",
    "LQGMPResult",
    "body_points",
    "joint_covariances",
    "lqgmp",
    "point_indices",
    "polygon_environment",
]


#: points checked inside each edge of a declared outline by the sigma and truncation methods
#: (evenly spaced; the sampling method tests the edges themselves)
OUTLINE_POINTS = 8


def point_indices(sim) -> tuple[np.ndarray, np.ndarray]:
    """``(collision (k, 2) int, goal (2,) int)``: where the 2-D points of the reduced state are.

    From ``sim.collision_point_indices`` / ``sim.goal_point_indices`` when the scenario
    defines them (manipulation: the sensed boundary points / the target), else ``x[:2]``
    for both (the needle's position).

    Parameters
    ----------
    sim : Simulator
        The scenario (its optional point-index attributes and ``state_dim``).

    Returns
    -------
    tuple of numpy.ndarray
        ``collision (k, 2)`` and ``goal (2,)`` int64 indices into the reduced state.
    """
    col = np.asarray(getattr(sim, "collision_point_indices", ((0, 1),)), dtype=np.int64).reshape(
        -1, 2
    )
    goal = np.asarray(getattr(sim, "goal_point_indices", (0, 1)), dtype=np.int64).reshape(2)
    p = sim.state_dim
    if col.min() < 0 or col.max() >= p or goal.min() < 0 or goal.max() >= p:
        raise InvalidInputError(
            f"collision_point_indices/goal_point_indices: expected indices in [0, {p})"
        )
    return col, goal


def body_points(sim, plan: NominalPlan, t: int, col: np.ndarray):
    """The 2-D points of the body that LQG-MP checks at step ``t``:
    ``(base (n, 2), a (n,), b (n,), lam (n,), outline)``.

    Point ``r`` is ``base[r] + (1 − lam[r]) d_a + lam[r] d_b`` where ``d_i`` is the
    deviation ``x_t − x*_t`` of the collision point ``col[i]`` (``a``, ``b`` rows of
    ``collision_point_indices``). By default these are the collision points themselves
    (``base = x*_t[col]``, ``a = b``, ``lam = 0``, ``outline = False``). A simulator whose body
    is wider than its reduced state's points declares ``collision_outline(state)`` returning
    ``(base, a, b, lam)`` for the nominal state ``y*_t``: the points of the body's outline
    (a closed polygon, in order), each moving with an interpolation of the deviations of
    two collision points. Then ``outline = True`` and LQG-MP also checks the outline's edges
    (module docstring). The manipulation declares its deformed boundary nodes, each interpolated
    by arc length between the two sensed points around it (its 12 sensed points are 0.28 apart,
    wider than the 0.14 obstacle: alone they call free an outline round an obstacle corner).

    Parameters
    ----------
    sim : Simulator
        The scenario (its optional ``collision_outline``).
    plan : NominalPlan
        The nominal plan.
    t : int
        The step.
    col : numpy.ndarray
        ``(k, 2)`` collision point indices (:func:`point_indices`).

    Returns
    -------
    tuple
        ``(base (n, 2), a (n,), b (n,), lam (n,), outline: bool)``.
    """
    hook = getattr(sim, "collision_outline", None)
    k = len(col)
    if hook is None:
        idx = np.arange(k)
        return plan.reduced[t][col], idx, idx, np.zeros(k), False
    base, a, b, lam = hook(plan.states[t])
    base = np.asarray(base, dtype=np.float64)
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    lam = np.asarray(lam, dtype=np.float64)
    n = len(base)
    if (
        base.shape != (n, 2)
        or n < 2
        or a.shape != (n,)
        or b.shape != (n,)
        or lam.shape != (n,)
        or not np.all(np.isfinite(base))
        or a.min() < 0
        or b.min() < 0
        or max(a.max(), b.max()) >= k
        or not np.all((lam >= 0) & (lam <= 1))
    ):
        raise InvalidInputError(
            "collision_outline: expected (points (n, 2) finite, a (n,), b (n,) in "
            f"[0, {k}), lam (n,) in [0, 1]) with n >= 2"
        )
    return base, a, b, lam, True


def _obstacles(sim, state) -> list:
    """The obstacles of ``state`` in the reduced state's coordinates:
    ``sim.state_obstacles(state)`` where the simulator defines it (a reduced state in
    another frame than the obstacles', e.g. the needle's material frame), else
    ``sim.obstacles(state)``."""
    hook = getattr(sim, "state_obstacles", None)
    return hook(state) if hook is not None else sim.obstacles(state)


def _goal(sim, state) -> np.ndarray:
    """The goal polygon of ``state`` in the reduced state's coordinates
    (``sim.state_goal`` where defined, else ``sim.goal``)."""
    hook = getattr(sim, "state_goal", None)
    return hook(state) if hook is not None else sim.goal(state)


def _weights(body, k):
    """``(base (n, 2), W (n, k), n_vertices)``: the checked points of a body
    (:func:`body_points`) as ``base + W d`` (``d (k, 2)`` the collision points' deviations).
    With an outline, :data:`OUTLINE_POINTS` points inside each edge follow its vertices."""
    base, a, b, lam, outline = body
    n = len(base)
    W = np.zeros((n, k))
    W[np.arange(n), a] += 1.0 - lam
    W[np.arange(n), b] += lam
    if not outline:
        return base, W, n
    nxt = np.roll(np.arange(n), -1)
    s = (np.arange(1, OUTLINE_POINTS + 1) / (OUTLINE_POINTS + 1))[:, None, None]
    Wi = ((1.0 - s) * W[None] + s * W[nxt][None]).reshape(-1, k)
    bi = ((1.0 - s) * base[None] + s * base[nxt][None]).reshape(-1, 2)
    return np.concatenate([base, bi]), np.concatenate([W, Wi]), n


def _outline_meets(polys, ring) -> bool:
    """True if the closed polygon ``ring (n, 2)`` meets one of ``polys``."""
    from riskplan import geometry2d as geo

    return any(geo.polygons_intersect(ring, q) for q in polys)


def polygon_environment(polygons):
    """A 2-D :class:`~riskplan.collision.Environment` from simple polygons, without the
    self-intersection check (``Environment.from_polygons(validate=False)``): the scenarios'
    deformed polygons stay simple, and this runs once per plan step.

    Parameters
    ----------
    polygons : sequence of array_like
        Simple polygons ``(k_i, 2)``.

    Returns
    -------
    Environment
        The 2-D environment of the polygons.
    """
    from riskplan.collision import Environment

    return Environment.from_polygons(polygons, validate=False)


def _edges(polys) -> tuple[np.ndarray, np.ndarray]:
    """Edge start points ``(E, 2)`` and end points ``(E, 2)`` of polygons."""
    a = np.concatenate([np.asarray(p, dtype=np.float64) for p in polys])
    b = np.concatenate([np.roll(np.asarray(p, dtype=np.float64), -1, axis=0) for p in polys])
    return a, b


def sigma_distances(starts, ends, points, covs) -> tuple[np.ndarray, np.ndarray]:
    """Batched σ-distances: ``(c (...,), inside (...,))`` for points ``(..., 2)`` with
    covariances ``(..., 2, 2)`` against polygons given by edge ``starts``/``ends`` ``(..., E, 2)``.

    ``c`` is the Mahalanobis distance from the point to the nearest edge (whitening with
    :func:`riskplan.collision.whiten`, then the Euclidean distance of the origin to each
    whitened segment); ``inside`` is the crossing-number test of the point against the
    polygons. Equal to the first half-space distance of :func:`riskplan.collision.free_region`.
    """
    from riskplan.collision import precision_cholesky_from_covariance, whiten

    U = precision_cholesky_from_covariance(covs)
    wa = whiten(starts, points, U)
    wb = whiten(ends, points, U)
    d = wb - wa
    tt = np.clip(
        -np.einsum("...i,...i->...", wa, d) / np.maximum(np.einsum("...i,...i->...", d, d), 1e-300),
        0.0,
        1.0,
    )
    closest = wa + tt[..., None] * d
    c = np.sqrt(np.einsum("...i,...i->...", closest, closest).min(axis=-1))
    # crossing number (edges of all polygons together: polygons do not overlap)
    P = points[..., None, :]
    ya, yb = starts[..., 1], ends[..., 1]
    cond = (ya > P[..., 1]) != (yb > P[..., 1])
    xint = starts[..., 0] + (P[..., 1] - ya) * (ends[..., 0] - starts[..., 0]) / np.where(
        yb != ya, yb - ya, 1.0
    )
    inside = (np.count_nonzero(cond & (P[..., 0] < xint), axis=-1) % 2) == 1
    return c, inside


def _sigma_free(sim, plan, mean, cov, col, p) -> np.ndarray | None:
    """Vectorised ``method="sigma"`` over all steps and points; None if the obstacle
    polygons or the body points change size along the plan (then the per-step loop runs)."""
    T = plan.n_steps
    polys = [_obstacles(sim, plan.states[t + 1]) for t in range(T)]
    if not len(polys[0]):
        return np.ones(T)
    sizes = {tuple(len(q) for q in ps) for ps in polys}
    if len(sizes) != 1:
        return None
    bodies = [body_points(sim, plan, t + 1, col) for t in range(T)]
    if len({len(bd[0]) for bd in bodies}) != 1 or len({bd[1].tobytes() for bd in bodies}) != 1:
        return None
    if len({bd[2].tobytes() + bd[3].tobytes() for bd in bodies}) != 1:
        return None
    outline = bodies[0][4]
    k = len(col)
    dense = [_weights(bd, k) for bd in bodies]
    W, nv = dense[0][1], dense[0][2]
    base = np.stack([d[0] for d in dense])  # (T, n, 2)
    E = [_edges(ps) for ps in polys]
    starts = np.stack([e[0] for e in E])[:, None]  # (T, 1, E, 2)
    ends = np.stack([e[1] for e in E])[:, None]
    pts, covs = _mix(col, W, base, mean[1:, :p], cov[1:])
    ev = np.linalg.eigvalsh(covs)
    ok = ev[..., -1] > 1e-24
    # a covariance of rank 1 (e.g. the needle under material draws: the tissue's offset of
    # the robot only scales with 1/E) has no Cholesky factor; only such a near-singular one
    # gets a jitter of 1e-9 of its largest variance (its spread direction keeps its distances)
    jitter = np.where(ev[..., 0] <= 1e-12 * ev[..., -1], 1e-9 * ev[..., -1], 0.0)
    covs = np.where(ok[..., None, None], covs + jitter[..., None, None] * np.eye(2), np.eye(2))
    try:
        c, inside = sigma_distances(starts, ends, pts, covs)
    except InvalidInputError as exc:  # a degenerate model, not bad input (_point_factor)
        from riskplan.errors import NumericalError

        raise NumericalError(
            f"LQG-MP: a position covariance has no Cholesky factor ({exc})"
        ) from exc
    c = np.where(ok, c, np.inf)
    cmin = c.min(axis=1)
    free = np.where(np.isinf(cmin), 1.0, -np.expm1(-0.5 * np.minimum(cmin, 1e150) ** 2))
    hit = inside.any(axis=1)
    if outline:
        hit |= np.array([_outline_meets(polys[t], pts[t, :nv]) for t in range(T)])
    return np.where(hit, 0.0, free)


def _sampled(sim, plan, controller, F, Qn, dm, mean, cov, col, goal_idx, n, seed) -> LQGMPResult:
    """``method="sampling"``: ``n`` joint trajectories of the linear-Gaussian recursion."""
    from riskplan import geometry2d as geo

    gen = as_generator(seed)
    T = plan.n_steps
    n = int(n)
    alive = np.ones(n, dtype=bool)
    free = np.ones(T)
    for t, xi in _closed_loop_draws(gen, n, T, controller.P0, F, dm, Qn):
        polys = _obstacles(sim, plan.states[t + 1])
        if not len(polys):
            continue
        env = polygon_environment(polys)
        before = int(alive.sum())
        if before == 0:
            free[t] = 0.0
            continue
        idx = np.flatnonzero(alive)
        live = xi[idx]
        bd = body_points(sim, plan, t + 1, col)
        outline = bd[4]
        base, W, nv = _weights(bd, len(col))
        base, W = base[:nv], W[:nv]  # the edges themselves are tested below
        body = base + np.einsum("rk,mkd->mrd", W, live[:, col])  # (m, nb, 2)
        m, nb = body.shape[:2]
        hit = np.asarray(env.contains(body.reshape(-1, 2)), dtype=bool).reshape(m, nb).any(axis=1)
        if outline:
            s0, s1 = _edges(polys)
            nxt = np.roll(body, -1, axis=1)
            edge_hit = geo.segments_hit(
                np.concatenate([s0, s1], axis=1), body.reshape(-1, 2), nxt.reshape(-1, 2)
            )
            hit |= edge_hit.reshape(m, nb).any(axis=1)
        alive[idx[hit]] = False
        free[t] = float(alive.sum()) / before
    goal_env = polygon_environment([_goal(sim, plan.states[T])])
    in_goal = np.asarray(goal_env.contains(plan.reduced[T][goal_idx] + xi[:, goal_idx]), dtype=bool)
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


def _goal_probability(sim, plan, mean_x, cov_x, goal_idx, n_goal_samples, seed) -> float:
    """P(goal): the fraction of ``n_goal_samples`` draws of the final true state
    ``N(x*_T + mean_x, cov_x)`` whose goal point lies in the goal region."""
    T = plan.n_steps
    p = mean_x.shape[0]
    gen = as_generator(seed)
    w, v = np.linalg.eigh(0.5 * (cov_x + cov_x.T))
    fac = v * np.sqrt(np.clip(w, 0.0, None))
    xT = plan.reduced[T] + mean_x + gen.standard_normal((int(n_goal_samples), p)) @ fac.T
    goal_env = polygon_environment([_goal(sim, plan.states[T])])
    return float(goal_env.contains(xT[:, goal_idx]).mean())


def _joint_start(controller, drift: bool, T: int):
    """``F (T, 2n, 2n)``, ``Q (T, 2n, 2n)``, ``d (T, 2n)`` of the joint recursion
    (:func:`~riskplan.control.lqgmp_common.joint_covariances`) and the arrays ``mean (T + 1, 2n)``,
    ``cov (T + 1, 2n, 2n)`` it fills, with ``μ_0 = 0`` and ``Σ_0 = diag(P_0, 0)``."""
    F, Qn, dm = joint_covariances(controller, drift)
    nz = F.shape[1] // 2  # p, or p + q with the disturbance state
    mean = np.zeros((T + 1, 2 * nz))
    cov = np.zeros((T + 1, 2 * nz, 2 * nz))
    cov[0, :nz, :nz] = controller.P0
    return F, Qn, dm, mean, cov


def _propagate(F, Qn, dm, mean, cov) -> None:
    """The joint recursion ``μ_{t+1} = F_t μ_t + d_t``, ``Σ_{t+1} = F_t Σ_t F_tᵀ + Q_t``
    (symmetrised) along the whole plan, written into ``mean (T + 1, 2n)`` and ``cov
    (T + 1, 2n, 2n)`` from their rows 0, and checked."""
    mu = np.zeros(mean.shape[1])
    S = cov[0].copy()
    for t in range(len(F)):
        mean[t + 1] = mu = F[t] @ mu + dm[t]
        S = F[t] @ S @ F[t].T + Qn[t]
        cov[t + 1] = S = 0.5 * (S + S.T)
    _check_propagation(mean, cov)


def _step_by_step(sim, plan, F, Qn, dm, mean, cov, col, p, truncating, cutoff) -> np.ndarray:
    """The per-step factors ``(T,)`` of ``P(no collision)``, step by step: the recursion
    (as :func:`_propagate`, into ``mean`` and ``cov``), the body's points against the
    obstacles of the deformed state ``y*_{t+1}`` (a mean point inside one: factor 0), and
    the sigma factor or, with ``truncating``, the truncation of the distribution by the
    nearest half-space (Patil 2012)."""
    T = plan.n_steps
    free = np.ones(T)
    mu = np.zeros(F.shape[1])
    S = cov[0].copy()
    for t in range(T):
        mu = F[t] @ mu + dm[t]
        S = F[t] @ S @ F[t].T + Qn[t]
        S = 0.5 * (S + S.T)
        _check_propagation(mu[None], S[None], t + 1)  # before any geometry sees it
        y = plan.states[t + 1]
        polys = _obstacles(sim, y)
        if not len(polys):
            mean[t + 1], cov[t + 1] = mu, S
            continue
        env = polygon_environment(polys)
        bd = body_points(sim, plan, t + 1, col)
        outline = bd[4]
        base, W, nv = _weights(bd, len(col))
        pts, covs = _mix(col, W, base, mu[:p], S)  # (n, 2), (n, 2, 2)
        if bool(env.contains(pts).any()) or (outline and _outline_meets(polys, pts[:nv])):
            free[t] = 0.0
            mean[t + 1], cov[t + 1] = mu, S
            continue
        if truncating:
            mu, S, free[t] = _truncation_step(col, W, base, mu, S, p, env, t, cutoff)
        else:
            free[t] = _sigma_step(pts, covs, env, t, cutoff)
        mean[t + 1], cov[t + 1] = mu, S
    return free


def lqgmp(
    sim,
    plan: NominalPlan,
    controller: LQGController,
    *,
    method: str = "sigma",
    n_goal_samples: int = 2000,
    cutoff: float | None = None,
    drift: bool = False,
    seed=None,
    **options_3d,
) -> LQGMPResult:
    r"""LQG-MP probability of success of ``plan`` under ``controller`` (paper IV-D).

    The joint deviation :math:`\xi_t = (\bar x_t, \hat x_t)` evolves as
    :math:`\xi_{t+1} = F_t \xi_t + G_t (m_t, n_t)` with

    .. math::

        F_t = \begin{bmatrix} A_t & B_t L_t \\ K_t H_t A_t & A_t + B_t L_t - K_t H_t A_t
        \end{bmatrix}, \qquad
        G_t = \begin{bmatrix} I & 0 \\ K_t H_t & K_t \end{bmatrix},

        \Sigma_{t+1} = F_t \Sigma_t F_t^\top + G_t \,\mathrm{diag}(M_t, N_t)\, G_t^\top,
        \qquad \Sigma_0 = \mathrm{diag}(P_0, 0),

    and, with :math:`c_t` the number of standard deviations to the nearest obstacle
    (``method="sigma"``),

    .. math::

        P(\text{success}) = P(\text{goal}) \prod_t \left(1 - e^{-c_t^2 / 2}\right)

    (module docstring for ``"truncation"`` and ``"sampling"``).

    Parameters
    ----------
    sim : Simulator
        The simulator (``obstacles(state)``, ``goal(state)``, optional point indices).
    plan : NominalPlan
        The plan with ``T`` steps.
    controller : LQGController
        The controller of the plan's linearisation.
    method : {"sigma", "truncation", "sampling"}
        The paper's, Patil 2012's, or whole trajectories of the linear model.
    n_goal_samples : int
        Draws of the final state for ``P(goal)``; with ``"sampling"``, the number of
        trajectories.
    cutoff : float, optional
        Whitened radius of the free-region construction (default
        :data:`riskplan.collision.DEFAULT_CUTOFF`, see :mod:`riskplan.collision.gaussian`).
    drift : bool
        Carry the mean one-step deviation ``lin.drift`` (beyond the paper, whose model is
        zero-mean): ``μ_{t+1} = F_t μ_t + G_t (d̄_t, 0)`` with ``M_t − d̄_t d̄_tᵀ`` as the
        process noise covariance.
    seed : int, numpy.random.Generator or None
        Seeds the goal samples (the trajectories with ``"sampling"``).
    **options_3d
        The 3-D model's own keywords (``goal``, ``goal_motion``, ``moments``, ``goal_se``,
        ``max_goal_samples``, ...), handed to :func:`riskplan.control.lqgmp3d.lqgmp_3d`
        unchanged; :class:`~riskplan.errors.InvalidInputError` for a 2-D simulator.

    Returns
    -------
    LQGMPResult
        ``p_success``, ``p_collision_free``, ``p_goal``, per-step factors and the
        distributions.

    Notes
    -----
    A simulator with ``workspace_dim = 3`` (the 3-D needle) is evaluated by
    :func:`riskplan.control.lqgmp3d.lqgmp_3d` against its 3-D convex obstacles, with every
    argument of this call: the two calls give the same result.
    """
    from riskplan.collision import DEFAULT_CUTOFF

    cutoff = DEFAULT_CUTOFF if cutoff is None else float(cutoff)
    args = dict(method=method, n_goal_samples=n_goal_samples, cutoff=cutoff, drift=drift, seed=seed)
    if getattr(sim, "workspace_dim", 2) == 3:  # 3-D convex obstacles (the 3-D needle)
        return lqgmp_3d(sim, plan, controller, **args, **options_3d)
    if options_3d:
        what = ", ".join(sorted(options_3d))
        raise InvalidInputError(f"{what}: options of the 3-D model (workspace_dim = 3) only")
    if method not in METHODS:
        raise InvalidInputError(f"method: expected one of {METHODS}, got {method!r}")
    _check_arguments(plan, controller, n_goal_samples)
    col, goal_idx = point_indices(sim)
    T = plan.n_steps
    p = plan.reduced.shape[1]
    F, Qn, dm, mean, cov = _joint_start(controller, drift, T)
    truncating = method == "truncation"
    fast = None
    if not truncating:
        _propagate(F, Qn, dm, mean, cov)
        if method == "sampling":
            rest = (F, Qn, dm, mean, cov, col, goal_idx, n_goal_samples, seed)
            return _sampled(sim, plan, controller, *rest)
        fast = _sigma_free(sim, plan, mean, cov, col, p)
    free = fast
    if fast is None:
        free = _step_by_step(sim, plan, F, Qn, dm, mean, cov, col, p, truncating, cutoff)
    _check_propagation(mean, cov)
    p_free = float(np.prod(free))
    p_goal = _goal_probability(
        sim, plan, mean[T, :p], cov[T, :p, :p], goal_idx, n_goal_samples, seed
    )
    return LQGMPResult(
        p_success=p_free * p_goal,
        p_collision_free=p_free,
        p_goal=p_goal,
        p_free_steps=free,
        mean=mean,
        cov=cov,
        method=method,
    )
