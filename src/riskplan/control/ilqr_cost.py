r"""The goal and obstacle terms of :mod:`riskplan.control.ilqr`'s cost: the barrier

.. math::

    b(x) = \sum_{t=1}^{T} \sum_j \sum_{O \in \mathcal{O}_t} w\, e^{-d_O(p_j(x_t))/\delta}

on the signed distance ``d_O`` (negative inside) of the body points ``p_j(x_t)`` to the
obstacle polygons of step ``t``, with its gradient ``φ'(d) n`` and Gauss–Newton Hessian
``φ''(d) n nᵀ`` (``φ(d) = w exp(−d/δ)``, ``n = ∇d``; the omitted ``φ'(d) (I − n nᵀ)/d``
beyond a vertex is negative semi-definite), and the goal and obstacles read from a 2-D
scenario (``scenario_terms``). Module docstring of :mod:`riskplan.control.ilqr` for the
whole cost.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan.control.plan import NominalPlan
from riskplan.errors import InvalidInputError

__all__ = [
    "BARRIER_SCALE",
    "BARRIER_WEIGHT",
    "GOAL_WEIGHT",
    "obstacle_barrier",
    "scenario_terms",
    "signed_distance",
]

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


def _make_barrier(plan, obstacles, points, body, weight, scale) -> _Barrier:
    """The barrier of :mod:`riskplan.control.ilqr`'s ``ilqr`` from its arguments,
    checked (3-D convex bodies: ``make_barrier_3d`` of :mod:`riskplan.control.ilqr_cost3d`):
    ``T + 1`` steps of polygons, point indices inside the reduced state, ``T + 1``
    body steps (default the collision points themselves), ``w ≥ 0``, ``δ > 0``."""
    from riskplan.geometry3d import ConvexBody

    if any(isinstance(o, ConvexBody) for step in obstacles for o in step):
        from riskplan.control.ilqr_cost3d import make_barrier_3d

        return make_barrier_3d(plan, obstacles, points, body, weight, scale)
    T, p = plan.n_steps, plan.reduced.shape[1]
    obstacles = tuple(
        tuple(np.asarray(o, dtype=np.float64).reshape(-1, 2) for o in step) for step in obstacles
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
    obstacle_barrier(np.zeros((1, 2)), (), weight, scale)  # checks w and δ
    return _Barrier(obstacles, idx, base, Ws, np.asarray(plan.reduced), float(weight), float(scale))


def scenario_terms(
    sim,
    plan: NominalPlan,
    *,
    goal_weight: float = GOAL_WEIGHT,
    barrier_weight: float = BARRIER_WEIGHT,
    barrier_scale: float = BARRIER_SCALE,
) -> dict:
    """The goal and obstacle terms of :func:`~riskplan.control.ilqr.ilqr` read from a 2-D scenario, in the reduced
    state's coordinates as LQG-MP reads them (:mod:`riskplan.control.lqgmp`); a 3-D
    scenario (``workspace_dim = 3``) is handed to
    :func:`~riskplan.control.ilqr_cost3d.scenario_terms_3d`.

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
        A 2-D scenario (or a 3-D one, above).
    plan : NominalPlan
        The reference plan.
    goal_weight, barrier_weight, barrier_scale : float
        :data:`GOAL_WEIGHT`, :data:`BARRIER_WEIGHT`, :data:`BARRIER_SCALE`.

    Returns
    -------
    dict
        Keyword arguments of :func:`~riskplan.control.ilqr.ilqr`: ``goal``, ``Q_goal``, ``obstacles``, ``points``,
        ``body``, ``barrier_weight``, ``barrier_scale``.
    """
    if getattr(sim, "workspace_dim", 2) == 3:
        from riskplan.control.ilqr_cost3d import scenario_terms_3d

        return scenario_terms_3d(
            sim,
            plan,
            goal_weight=goal_weight,
            barrier_weight=barrier_weight,
            barrier_scale=barrier_scale,
        )
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
