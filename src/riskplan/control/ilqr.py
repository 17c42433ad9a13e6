r"""Iterative LQR around a nominal plan (Li & Todorov, ICINCO 2004; Tassa, Erez & Todorov,
IROS 2012 for the regularisation and line search), on the simulator's numerical
linearisation (:func:`~riskplan.control.linearize`); beyond the deformable-planning paper,
whose nominal plan is the RRT's and is only tracked.

Cost of the controls ``u_0 .. u_{T-1}`` rolled out on the simulator (nominal parameters)
from the plan's start, with the plan ``(x*, u*)`` as reference and a goal ``g``::

    J = Σ_{t<T} (x_t − x*_t)ᵀ Q (x_t − x*_t) + (u_t − u*_t)ᵀ R (u_t − u*_t)
        + (x_T − x*_T)ᵀ Q_final (x_T − x*_T) + (x_T − g)ᵀ Q_goal (x_T − g)
        + Σ_{1≤t≤T} Σ_j Σ_{O ∈ 𝒪_t} w exp(−d_O(P_j x_t) / δ)

.. math::

    J(u) = \sum_{t<T} \bigl(\|x_t - x^*_t\|_Q^2 + \|u_t - u^*_t\|_R^2\bigr)
        + \|x_T - x^*_T\|_{Q_f}^2 + \|x_T - g\|_{Q_g}^2
        + \sum_{t=1}^{T} \sum_j \sum_{O \in \mathcal{O}_t} w\, e^{-d_O(P_j x_t)/\delta}

The last term is the obstacle barrier (optional, ``obstacles``): ``P_j x_t`` the ``j``-th
2-D collision point of the reduced state (``points``, the scenario's
``collision_point_indices``), ``𝒪_t`` the obstacle polygons of step ``t`` in the reduced
state's coordinates (the reference plan's: held fixed while iterating, as LQG-MP reads them
at ``y*_t``), ``d_O`` the signed distance to polygon ``O`` (negative inside), ``w`` the
weight and ``δ`` the length over which it decays (:func:`obstacle_barrier`). Its gradient is
``φ'(d) n`` with ``n = ∇d`` the unit normal from the nearest boundary point and
``φ'(d) = −φ(d)/δ``; its Hessian is taken in the Gauss–Newton form ``φ''(d) n nᵀ``
(``φ'' = φ/δ² ≥ 0``, so ``Q_xx`` stays positive semi-definite), which omits
``φ'(d) ∇²d = φ'(d) (I − n nᵀ)/|P_j x_t − c|`` where the nearest boundary point ``c`` is a
vertex (zero along an edge; negative semi-definite since ``φ' < 0``). The goal enters as
the terminal ``(x_T − g)ᵀ Q_goal (x_T − g)`` (:func:`scenario_terms` builds ``g``,
``Q_goal`` and the obstacles from a scenario).

The expected cost under the linearised noise, ``x_{t+1} = A_t x_t + B_t u_t + m_t``,
``m_t ~ N(0, M_t)``, adds ``Σ_t tr(S_{t+1} M_t)``; with ``M_t`` held at the plan's (not
re-fitted along each iterate) that term does not depend on the controls, so minimising
``J`` minimises the expected cost of this model (iLQG with additive noise).

Iteration ``i``: linearise about the current trajectory ``(x̄, ū)`` (``A_t``, ``B_t``),
backward pass (``V_x``, ``V_xx`` from ``T``, where they are the terminal terms' gradient and Hessian plus
the barrier's ``b_x``, ``b_xx``; ``μ`` the Levenberg–Marquardt regularisation)::

    Q_u = R (ū_t − u*_t) + B_tᵀ V_x,    Q_x = Q (x̄_t − x*_t) + b_x(x̄_t) + A_tᵀ V_x
    Q_uu = R + B_tᵀ V_xx B_t + μ I,    Q_ux = B_tᵀ V_xx A_t,    Q_xx = Q + b_xx(x̄_t) + A_tᵀ V_xx A_t
    k_t = −Q_uu⁻¹ Q_u,   K_t = −Q_uu⁻¹ Q_ux
    V_x ← Q_x + K_tᵀ Q_uu k_t + K_tᵀ Q_u + Q_uxᵀ k_t,   V_xx ← Q_xx + K_tᵀ Q_uu K_t + K_tᵀ Q_ux + Q_uxᵀ K_t

forward pass with line search ``α ∈ {1, ½, ¼, …}``:
``u_t = clip(ū_t + α k_t + K_t (x_t − x̄_t))`` rolled out on the simulator; the first ``α``
that lowers ``J`` is accepted (``μ`` shrinks), none raises ``μ ×10``. It stops when the
relative decrease is below ``tol`` or after ``max_iter`` iterations. The cost therefore
never increases from one accepted iterate to the next (the property the tests check).

On a linear system with quadratic cost the backward pass is exact, so one iteration with
``α = 1`` reaches the optimum and ``K_t`` equals :func:`~riskplan.control.lqr_gains` with
``Q_final + Q_goal`` (the tests' oracle, against the least-squares solution of the
stacked problem as well).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan.control.plan import NominalPlan
from riskplan.errors import ConvergenceError, InvalidInputError, SimulationError

__all__ = [
    "BARRIER_SCALE",
    "BARRIER_WEIGHT",
    "GOAL_WEIGHT",
    "ILQRResult",
    "ilqr",
    "obstacle_barrier",
    "scenario_terms",
    "signed_distance",
    "tracking_controller",
]

#: Regularisation at which the search gives up on a descent step: the iterate is then a
#: local minimum of ``J`` to the model's accuracy.
MU_MAX = 1e4


@dataclass(frozen=True, eq=False)
class ILQRResult:
    """Result of :func:`ilqr`: the re-optimised ``plan``, the feedback ``K (T, q, p)`` of
    the last backward pass (``u_t = u_t + K_t (x_t − x̄_t)``), ``costs`` the cost of every
    accepted iterate (``costs[0]`` the input plan's), ``iterations``, ``converged``, and
    ``n_linearizations`` (the extra computation: one simulator linearisation each)."""

    plan: NominalPlan
    K: np.ndarray
    costs: np.ndarray
    iterations: int
    converged: bool
    n_linearizations: int


#: Default barrier weight ``w``: touching an obstacle (``d = 0``) costs as much per step as a
#: deviation of one Bryson scale from the plan (the tracking cost's unit).
BARRIER_WEIGHT = 1.0
#: Default decay length ``δ`` of the barrier, in units of the collision point's Bryson
#: scale (the deviation the tracking cost tolerates): at ``d = 3 δ`` the barrier is 5 % of
#: ``w``, so it acts only on plans that pass within a few tolerated deviations of an obstacle.
BARRIER_SCALE = 1.0
#: Default goal weight: ``Q_goal = GOAL_WEIGHT / r² I`` on the goal point, ``r`` the goal's
#: radius, so ending one radius from the goal's centre costs as much as ten Bryson deviations.
GOAL_WEIGHT = 10.0


def _signed_distances(P, V):
    """Batched :func:`signed_distance`: points ``P (B, n, 2)`` against polygons
    ``V (B, m, 2)``; returns ``d (B, n)``, ``normal (B, n, 2)``, ``at_vertex (B, n)``.
    Inside by the crossing number (even–odd) of a ray in ``+x``."""
    a = V
    e = np.roll(V, -1, axis=1) - V  # (B, m, 2)
    ee = np.maximum(np.einsum("bmi,bmi->bm", e, e), 1e-300)
    rel = P[:, :, None, :] - a[:, None, :, :]  # (B, n, m, 2)
    s = np.clip(np.einsum("bnmi,bmi->bnm", rel, e) / ee[:, None, :], 0.0, 1.0)
    r = rel - s[..., None] * e[:, None, :, :]  # from the nearest point of every edge
    dist = np.sqrt(np.einsum("bnmi,bnmi->bnm", r, r))
    j = np.argmin(dist, axis=2)[..., None]
    dmin = np.take_along_axis(dist, j, axis=2)[..., 0]
    rj = np.take_along_axis(r, j[..., None], axis=2)[:, :, 0, :]
    sj = np.take_along_axis(s, j, axis=2)[..., 0]
    ay, by = a[:, None, :, 1], a[:, None, :, 1] + e[:, None, :, 1]
    py, px = P[:, :, None, 1], P[:, :, None, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = a[:, None, :, 0] + e[:, None, :, 0] * (py - ay) / (by - ay)
    crosses = ((ay > py) != (by > py)) & (px < xc)
    sign = np.where(crosses.sum(axis=2) % 2 == 1, -1.0, 1.0)
    normal = sign[..., None] * rj / np.maximum(dmin, 1e-300)[..., None]
    return sign * dmin, normal, (sj <= 0.0) | (sj >= 1.0)


def signed_distance(points, polygon):
    """Signed distance of 2-D points to a simple polygon and its derivatives.

    ``d(p) = ± min_e |p − c_e(p)|``, ``c_e`` the nearest point of edge ``e``, negative inside
    (crossing-number test). Away from the medial axis ``∇d = n = ±(p − c)/|p − c|`` and
    ``∇²d = (I − n nᵀ)/d`` where the nearest boundary point is a vertex, ``0`` along an edge.

    Parameters
    ----------
    points : array_like
        ``(n, 2)`` points.
    polygon : array_like
        ``(m, 2)`` vertices of a simple polygon, in order, not repeated.

    Returns
    -------
    d : numpy.ndarray
        ``(n,)`` signed distances.
    normal : numpy.ndarray
        ``(n, 2)`` gradients ``∇d`` (unit vectors).
    at_vertex : numpy.ndarray
        ``(n,)`` bool, the nearest boundary point is a vertex (where ``∇²d ≠ 0``).
    """
    P = np.asarray(points, dtype=np.float64).reshape(1, -1, 2)
    V = np.asarray(polygon, dtype=np.float64).reshape(1, -1, 2)
    d, n, v = _signed_distances(P, V)
    return d[0], n[0], v[0]


def obstacle_barrier(points, polygons, weight: float = BARRIER_WEIGHT, scale: float = 1.0):
    """The barrier ``Σ_j Σ_O w exp(−d_O(p_j)/δ)`` of points against obstacle polygons, with
    its gradient and Gauss–Newton Hessian (module docstring).

    Parameters
    ----------
    points : array_like
        ``(n, 2)`` points ``p_j``.
    polygons : sequence of array_like
        Obstacle polygons ``(m_k, 2)``.
    weight : float
        ``w`` (cost at ``d = 0``).
    scale : float
        ``δ > 0``, the decay length.

    Returns
    -------
    value : float
        The barrier.
    grad : numpy.ndarray
        ``(n, 2)``, ``Σ_O φ'(d_O) n_O`` per point.
    hess : numpy.ndarray
        ``(n, 2, 2)``, ``Σ_O φ''(d_O) n_O n_Oᵀ`` per point (Gauss–Newton: positive
        semi-definite; the omitted ``φ'(d) ∇²d`` is :func:`signed_distance`'s curvature).
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if not (np.isfinite(scale) and scale > 0 and np.isfinite(weight) and weight >= 0):
        raise InvalidInputError(
            f"barrier: expected weight >= 0 and scale > 0, got {weight}, {scale}"
        )
    value, grad, hess = 0.0, np.zeros_like(P), np.zeros((len(P), 2, 2))
    for poly in polygons:
        d, n, _ = signed_distance(P, poly)
        phi = weight * np.exp(-d / scale)
        value += float(phi.sum())
        grad += (-phi / scale)[:, None] * n
        hess += (phi / scale**2)[:, None, None] * n[:, :, None] * n[:, None, :]
    return value, grad, hess


@dataclass(frozen=True, eq=False)
class _Barrier:
    """The obstacle term over a trajectory: ``obstacles[t]`` the polygons of step ``t``;
    ``col (k, 2)`` the reduced state's indices of the collision points; the checked points
    of step ``t`` are ``base[t] + W[t] (x_t[col] − x*_t[col])`` (``base[t] (n, 2)``,
    ``W[t] (n, k)``; by default the collision points themselves); ``w``, ``δ``."""

    obstacles: tuple
    col: np.ndarray
    base: tuple
    W: tuple
    ref: np.ndarray
    weight: float
    scale: float

    def _stacked(self):
        """``(steps (B,), V (B, m, 2))``: every (step, polygon) pair, the polygons padded to
        the most vertices by repeating their last vertex (a zero-length edge changes neither
        the distance nor the crossing count), for one batched distance call per
        trajectory; ``None`` when the steps check different numbers of points."""
        rows = [(t, o) for t in range(1, len(self.obstacles)) for o in self.obstacles[t]]
        if not rows or len({len(self.base[t]) for t, _ in rows}) != 1:
            return None
        m = max(len(o) for _, o in rows)
        V = np.stack([np.concatenate([o, np.repeat(o[-1:], m - len(o), axis=0)]) for _, o in rows])
        return np.array([t for t, _ in rows]), V

    def terms(self, x, derivatives: bool = True):
        """``(value, b_x (T + 1, p), b_xx (T + 1, p, p))`` along ``x (T + 1, p)`` (zero at
        ``t = 0``: the start is not controlled); the value alone with ``derivatives=False``
        (the line search)."""
        Tp1, p = x.shape
        k = len(self.col)
        flat = self.col.reshape(-1)
        dev = x[:, self.col] - self.ref[:, self.col]  # (T + 1, k, 2)
        stacked = self.__dict__.get("_stack", False)
        if stacked is False:
            stacked = self._stacked()
            object.__setattr__(self, "_stack", stacked)
        if stacked is not None:
            steps, V = stacked
            W = np.stack([self.W[t] for t in steps])  # (B, n, k)
            pts = np.stack([self.base[t] for t in steps]) + W @ dev[steps]
            d, nrm, _ = _signed_distances(pts, V)
            phi = self.weight * np.exp(-d / self.scale)  # (B, n)
            total = float(phi.sum())
            if not derivatives:
                return total
            g = (-phi / self.scale)[..., None] * nrm  # (B, n, 2)
            h = (phi / self.scale**2)[..., None, None] * nrm[..., :, None] * nrm[..., None, :]
            gc = np.einsum("bra,bri->bai", W, g).reshape(len(steps), 2 * k)
            hc = np.einsum("bra,brc,brij->baicj", W, W, h).reshape(len(steps), 2 * k, 2 * k)
            bx, bxx = np.zeros((Tp1, p)), np.zeros((Tp1, p, p))
            gt, ht = np.zeros((Tp1, 2 * k)), np.zeros((Tp1, 2 * k, 2 * k))
            np.add.at(gt, steps, gc)
            np.add.at(ht, steps, hc)
            bx[:, flat] = gt
            bxx[:, flat[:, None], flat[None, :]] = ht
            return total, bx, bxx
        bx, bxx, total = np.zeros((Tp1, p)), np.zeros((Tp1, p, p)), 0.0
        for t in range(1, Tp1):
            if not self.obstacles[t]:
                continue
            W = self.W[t]
            pts = self.base[t] + W @ dev[t]
            v, g, h = obstacle_barrier(pts, self.obstacles[t], self.weight, self.scale)
            total += v
            bx[t, flat] += (W.T @ g).reshape(-1)
            hc = np.einsum("ra,rb,rij->aibj", W, W, h).reshape(2 * k, 2 * k)
            bxx[t][np.ix_(flat, flat)] += hc
        return total if not derivatives else (total, bx, bxx)


def _cost(x, u, ref, Q, R, Qf, goal, Qg, barrier=None):
    dx, du = x[:-1] - ref.reduced[:-1], u - ref.controls
    e, g = x[-1] - ref.reduced[-1], x[-1] - goal
    b = 0.0 if barrier is None else barrier.terms(x, derivatives=False)
    return float(
        np.einsum("ti,ij,tj->", dx, Q, dx)
        + np.einsum("ti,ij,tj->", du, R, du)
        + e @ Qf @ e
        + g @ Qg @ g
        + b
    )


def _backward(A, B, x, u, ref, Q, R, Qf, goal, Qg, mu, bx, bxx):
    T, p, q = B.shape
    Vx = Qf @ (x[-1] - ref.reduced[-1]) + Qg @ (x[-1] - goal) + bx[-1]
    Vxx = Qf + Qg + bxx[-1]
    k = np.empty((T, q))
    K = np.empty((T, q, p))
    for t in range(T - 1, -1, -1):
        At, Bt = A[t], B[t]
        Qu = R @ (u[t] - ref.controls[t]) + Bt.T @ Vx
        Qx = Q @ (x[t] - ref.reduced[t]) + bx[t] + At.T @ Vx
        Quu = R + Bt.T @ Vxx @ Bt
        Qux = Bt.T @ Vxx @ At
        Qxx = Q + bxx[t] + At.T @ Vxx @ At
        try:
            np.linalg.cholesky(Quu + mu * np.eye(q))
        except np.linalg.LinAlgError:
            return None
        sol = -np.linalg.solve(Quu + mu * np.eye(q), np.column_stack([Qu, Qux]))
        k[t], K[t] = sol[:, 0], sol[:, 1:]
        Vx = Qx + K[t].T @ Quu @ k[t] + K[t].T @ Qu + Qux.T @ k[t]
        Vxx = Qxx + K[t].T @ Quu @ K[t] + K[t].T @ Qux + Qux.T @ K[t]
        Vxx = 0.5 * (Vxx + Vxx.T)
    return k, K


def _rollout(sim, plan, x, u, k, K, alpha, lo, hi):
    y = plan.states[0]
    states, xs, us = [y], [np.asarray(sim.reduced(y), dtype=np.float64)], np.empty_like(u)
    for t in range(u.shape[0]):
        us[t] = np.clip(u[t] + alpha * k[t] + K[t] @ (xs[t] - x[t]), lo, hi)
        y = sim.step(y, us[t], plan.params)
        xt = np.asarray(sim.reduced(y), dtype=np.float64)
        if not np.all(np.isfinite(xt)):
            raise SimulationError(f"step {t}: non-finite reduced state")
        states.append(y)
        xs.append(xt)
    return NominalPlan(states=tuple(states), controls=us, reduced=np.stack(xs), params=plan.params)


def ilqr(
    sim,
    plan: NominalPlan,
    Q,
    R,
    Q_final=None,
    goal=None,
    Q_goal=None,
    *,
    linearizer=None,
    max_iter: int = 10,
    tol: float = 1e-4,
    mu0: float = 1e-6,
    obstacles=None,
    points=((0, 1),),
    body=None,
    barrier_weight: float = BARRIER_WEIGHT,
    barrier_scale: float = 1.0,
) -> ILQRResult:
    """Re-optimise ``plan`` by iLQR on the simulator (module docstring).

    Parameters
    ----------
    sim : Simulator
        Rolled out under ``plan.params``.
    plan : NominalPlan
        The reference ``(x*, u*)`` and the first iterate.
    Q : array_like
        ``(p, p)`` state cost about ``x*``.
    R : array_like
        ``(q, q)`` control cost about ``u*``, positive definite.
    Q_final : array_like, optional
        ``(p, p)`` final cost about ``x*_T`` (default ``Q``).
    goal : array_like, optional
        ``(p,)`` goal ``g`` (default ``x*_T``).
    Q_goal : array_like, optional
        ``(p, p)`` goal cost (default zero).
    linearizer : callable, optional
        ``linearizer(plan) -> (A (T, p, p), B (T, p, q))``; default the ``A``, ``B`` of
        :func:`~riskplan.control.linearize` on the nominal parameters.
    max_iter : int
        Most iterations.
    tol : float
        Relative cost decrease that counts as converged.
    mu0 : float
        Initial regularisation ``μ``.
    obstacles : sequence, optional
        ``T + 1`` lists of obstacle polygons ``(m, 2)`` in the reduced state's coordinates,
        one per step (entry 0 unused): the barrier term (default none).
    points : array_like
        ``(k, 2)`` indices of the reduced state's 2-D collision points (default ``x[:2]``).
    body : sequence, optional
        ``T + 1`` pairs ``(base (n, 2), W (n, k))``: the points checked at step ``t`` are
        ``base + W (x_t[points] − x*_t[points])`` (a body wider than its collision points,
        e.g. :func:`~riskplan.control.lqgmp.body_points`' outline); default the collision
        points themselves.
    barrier_weight : float
        ``w`` of the barrier.
    barrier_scale : float
        ``δ`` of the barrier (length units of the points).

    Returns
    -------
    ILQRResult
        Plan, feedback, cost history, iterations, convergence flag.
    """
    from riskplan.control.linearize import linearize

    if not isinstance(plan, NominalPlan):
        raise InvalidInputError(f"plan: expected a NominalPlan, got {type(plan).__name__}")
    T, q = plan.controls.shape
    p = plan.reduced.shape[1]
    Q = np.asarray(Q, dtype=np.float64).reshape(p, p)
    R = np.asarray(R, dtype=np.float64).reshape(q, q)
    Qf = Q if Q_final is None else np.asarray(Q_final, dtype=np.float64).reshape(p, p)
    Qg = np.zeros((p, p)) if Q_goal is None else np.asarray(Q_goal, dtype=np.float64).reshape(p, p)
    goal = plan.reduced[-1] if goal is None else np.asarray(goal, dtype=np.float64).reshape(p)
    if linearizer is None:

        def linearizer(pl):
            lin = linearize(sim, pl, [pl.params], seed=0)
            return lin.A, lin.B

    barrier = None
    if obstacles is not None:
        obstacles = tuple(
            tuple(np.asarray(o, dtype=np.float64).reshape(-1, 2) for o in step)
            for step in obstacles
        )
        idx = np.asarray(points, dtype=np.int64).reshape(-1, 2)
        if len(obstacles) != T + 1 or idx.min() < 0 or idx.max() >= p:
            raise InvalidInputError(
                f"obstacles/points: expected {T + 1} steps of polygons and indices in [0, {p})"
            )
        k = len(idx)
        if body is None:
            body = [(plan.reduced[t][idx], np.eye(k)) for t in range(T + 1)]
        if len(body) != T + 1:
            raise InvalidInputError(f"body: expected {T + 1} steps, got {len(body)}")
        base = tuple(np.asarray(b, dtype=np.float64).reshape(-1, 2) for b, _ in body)
        Ws = tuple(
            np.asarray(w, dtype=np.float64).reshape(len(b_), k) for b_, (_, w) in zip(base, body)
        )
        barrier = _Barrier(
            obstacles,
            idx,
            base,
            Ws,
            np.asarray(plan.reduced),
            float(barrier_weight),
            float(barrier_scale),
        )
        obstacle_barrier(np.zeros((1, 2)), (), barrier.weight, barrier.scale)  # checks w, δ

    def terms(x):
        if barrier is None:
            return np.zeros((T + 1, p)), np.zeros((T + 1, p, p))
        return barrier.terms(x)[1:]

    def cost(pl):
        return _cost(pl.reduced, pl.controls, ref, Q, R, Qf, goal, Qg, barrier)

    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    lo, hi = bounds[:, 0], bounds[:, 1]
    ref, cur = plan, plan
    costs = [cost(cur)]
    mu, converged, n_lin, K = mu0, False, 0, np.zeros((T, q, p))
    for _ in range(max_iter):
        A, B = linearizer(cur)
        n_lin += 1
        x, u = np.asarray(cur.reduced), np.asarray(cur.controls)
        bx, bxx = terms(x)
        accepted = False
        while mu < MU_MAX and not accepted:
            bw = _backward(A, B, x, u, ref, Q, R, Qf, goal, Qg, mu, bx, bxx)
            if bw is None:
                mu *= 10.0
                continue
            k, K = bw
            for alpha in 0.5 ** np.arange(6):
                try:
                    cand = _rollout(sim, cur, x, u, k, K, alpha, lo, hi)
                except (ConvergenceError, SimulationError):
                    continue
                c = cost(cand)
                if c < costs[-1]:
                    accepted = True
                    break
            mu = max(mu / 10.0, 1e-12) if accepted else mu * 10.0
        if not accepted:
            converged = True  # no descent direction left at any regularisation
            break
        cur = cand
        costs.append(c)
        if costs[-2] - c <= tol * max(costs[-2], 1e-300):
            converged = True
            break
    return ILQRResult(
        plan=cur,
        K=K,
        costs=np.array(costs),
        iterations=n_lin,
        converged=converged,
        n_linearizations=n_lin,
    )


def scenario_terms(
    sim,
    plan: NominalPlan,
    *,
    goal_weight: float = GOAL_WEIGHT,
    barrier_weight: float = BARRIER_WEIGHT,
    barrier_scale: float = BARRIER_SCALE,
) -> dict:
    """The goal and obstacle terms of :func:`ilqr` read from a 2-D scenario, in the reduced
    state's coordinates as LQG-MP reads them (:mod:`riskplan.control.lqgmp`).

    * goal ``g``: ``x*_T`` with the goal point (``goal_point_indices``) moved to the centre
      of the goal polygon at ``y*_T`` (``state_goal``, else ``goal``; the mean of its
      vertices), ``Q_goal = goal_weight / r² I`` on the goal point, ``r`` the polygon's mean
      vertex distance from that centre (the goal disk's radius);
    * obstacles of every step ``t`` at ``y*_t`` (``state_obstacles``, else ``obstacles``),
      checked at the body's points (:func:`~riskplan.control.lqgmp.body_points`: the
      collision points, or the outline a scenario declares), ``w = barrier_weight``,
      ``δ = barrier_scale ×`` the mean Bryson scale of the collision points
      (``sim.state_scale``; 1 where none is declared).

    Parameters
    ----------
    sim : Simulator
        A 2-D scenario.
    plan : NominalPlan
        The reference plan.
    goal_weight, barrier_weight, barrier_scale : float
        :data:`GOAL_WEIGHT`, :data:`BARRIER_WEIGHT`, :data:`BARRIER_SCALE`.

    Returns
    -------
    dict
        Keyword arguments of :func:`ilqr`: ``goal``, ``Q_goal``, ``obstacles``, ``points``,
        ``body``, ``barrier_weight``, ``barrier_scale``.
    """
    from riskplan.control.lqgmp import _weights, body_points, point_indices

    col, gidx = point_indices(sim)
    p = plan.reduced.shape[1]
    hook = getattr(sim, "state_goal", None) or sim.goal
    poly = np.asarray(hook(plan.states[-1]), dtype=np.float64).reshape(-1, 2)
    centre = poly.mean(axis=0)
    r = float(np.mean(np.linalg.norm(poly - centre, axis=1)))
    goal = np.array(plan.reduced[-1], dtype=np.float64)
    goal[gidx] = centre
    Qg = np.zeros((p, p))
    Qg[gidx, gidx] = goal_weight / r**2
    ohook = getattr(sim, "state_obstacles", None) or sim.obstacles
    obstacles = [ohook(y) for y in plan.states]
    body = [_weights(body_points(sim, plan, t, col), len(col))[:2] for t in range(plan.n_steps + 1)]
    scale = getattr(sim, "state_scale", None)
    unit = 1.0 if scale is None else float(np.mean(np.asarray(scale)[col]))
    return dict(
        goal=goal,
        Q_goal=Qg,
        obstacles=obstacles,
        points=col,
        body=body,
        barrier_weight=float(barrier_weight),
        barrier_scale=float(barrier_scale) * unit,
    )


def tracking_controller(
    sim,
    plan: NominalPlan,
    distribution=None,
    *,
    controller: str = "lqr",
    goal=None,
    Q_goal=None,
    terms=None,
    max_iter: int = 5,
    n_samples: int = 16,
    seed=0,
):
    """The plan to execute and its LQG gains: the plan as given (``"lqr"``, the paper's) or
    re-optimised by :func:`ilqr` first (``"ilqr"``) with the default Bryson weights of
    :func:`~riskplan.control.lqg_controller`, then linearised under ``distribution``.

    Parameters
    ----------
    sim : Simulator
        The simulator.
    plan : NominalPlan
        The (RRT) plan.
    distribution : object, optional
        Parameter distribution for ``M_t`` (:func:`~riskplan.control.linearize`).
    controller : {"lqr", "ilqr"}
        Track the plan, or re-optimise it first.
    goal, Q_goal : array_like, optional
        The goal term of :func:`ilqr`.
    terms : dict, optional
        More keyword arguments of :func:`ilqr` (the goal and obstacle terms of
        :func:`scenario_terms`; they take precedence over ``goal``, ``Q_goal``).
    max_iter : int
        iLQR iterations at most.
    n_samples : int
        Parameter draws of the linearisation.
    seed : int
        Seed of the linearisation.

    Returns
    -------
    plan : NominalPlan
        The plan executed.
    lqg : LQGController
        Its gains.
    info : ILQRResult or None
        The iLQR result (``None`` for ``"lqr"``).
    """
    from riskplan.control.linearize import linearize
    from riskplan.control.lqg import bryson_weights, lqg_controller

    if controller not in ("lqr", "ilqr"):
        raise InvalidInputError(f"controller: expected 'lqr' or 'ilqr', got {controller!r}")
    info = None
    if controller == "ilqr":
        lin0 = linearize(sim, plan, [plan.params], seed=seed)  # only for the scales
        p, q = plan.reduced.shape[1], plan.controls.shape[1]
        Q = (
            np.eye(p)
            if lin0.state_scale is None
            else bryson_weights(lin0.state_scale, np.ones(1))[0]
        )
        R = (
            np.eye(q)
            if lin0.control_scale is None
            else bryson_weights(np.ones(1), lin0.control_scale)[1]
        )
        kw = {"goal": goal, "Q_goal": Q_goal, **(terms or {})}
        info = ilqr(sim, plan, Q, R, max_iter=max_iter, **kw)
        plan = info.plan
    lin = linearize(sim, plan, distribution, n_samples=n_samples, seed=seed)
    return plan, lqg_controller(lin), info
