r"""iLQR's obstacle barrier against 3-D convex bodies: the 3-D needle's deformed ellipsoids
and parallelepipeds (:class:`riskplan.geometry3d.ConvexBody`), the same barrier as the 2-D
one of :mod:`riskplan.control.ilqr_cost`,

.. math::

    b(x) = \sum_{t=1}^{T} \sum_j \sum_{O \in \mathcal{O}_t} w\, e^{-d_O(p_j(x_t))/\delta},

with ``d_O`` the exact Euclidean signed distance (negative inside) to the body
``O = {c + A s : s ∈ B}`` (``B`` the unit ball of the 2-norm or of the ∞-norm):

* **ellipsoid**, the point ``p`` outside or inside: the nearest boundary point is
  ``q = c + A s`` with ``|s| = 1`` minimising ``|a + A s|``, ``a = c − p``. Its stationarity
  condition ``(AᵀA + λ I) s = −Aᵀ a`` gives, in the eigenbasis ``AᵀA = V diag(w) Vᵀ``,
  ``b = Vᵀ Aᵀ a``, ``s(λ) = −V b / (w + λ)``, and the 1-D root of
  ``φ(λ) = |s(λ)|² − 1`` on ``(−w_min, |b| − w_min]`` (``φ`` falls monotonically there; the
  global minimiser has ``AᵀA + λ I ⪰ 0``; ``λ > 0`` outside, ``λ ≤ 0`` inside). It is
  found by bisection to round-off (the bracket is exact). In the hard case (``b`` has no
  component along the smallest axis, a point on the medial surface inside) the missing
  length of ``s`` is put along that axis, one of the equally near points;
* **box** (parallelepiped), outside: ``min |a + A s|²`` subject to ``|s_i| ≤ 1``, a convex
  quadratic programme in three variables solved exactly by trying its 26 active sets
  (each ``s_i`` at −1, +1 or free; all free is the interior) and keeping the best
  feasible one (the optimum's own active set is among them). Inside: the distance to the
  nearest face plane, ``min_{k,±} (1 ∓ s_k) / |A⁻ᵀ e_k|`` with ``s = A⁻¹ (p − c)``
  (for a convex polytope the nearest boundary point of an interior point lies on a face).

In both cases ``∇d = n``, the outward unit normal at the nearest boundary point
(``A⁻ᵀ s / |A⁻ᵀ s|`` on the ellipsoid; ``(p − q) / |p − q|`` outside the box, the face
normal inside). As in 2-D the backward pass takes the gradient ``φ'(d) n`` and the
Gauss–Newton Hessian ``φ''(d) n nᵀ``; the omitted ``φ'(d) ∇²d`` is negative
semi-definite outside a convex body (``d`` is convex there and ``φ' < 0``), and
``∇²d n = 0`` (``d`` grows at unit rate along ``n``), so along ``n`` the Gauss–Newton
curvature is exact (the tests check both with finite differences).

The bodies of step ``t`` are the scenario's deformed ones at the reference plan's state
``y*_t`` (:meth:`~riskplan.scenarios.needle3d.Needle3DScenario.state_obstacles`: the affine
images the collision test checks the tip against), held fixed while iterating, as the 2-D
barrier and LQG-MP read them.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from riskplan.control.plan import NominalPlan
from riskplan.errors import InvalidInputError
from riskplan.geometry3d import ConvexBody

__all__ = ["body_signed_distance", "obstacle_barrier_3d", "scenario_terms_3d"]

#: Bisection steps of the ellipsoid's secular equation: the bracket ``(−w_min, |b| − w_min]``
#: (of ``λ + w_min``: ``(0, |b|]``) halves to below float64 round-off well within 80 steps.
_BISECTIONS = 80
#: The 26 active sets of the box's exterior problem (every pattern but "all free").
_PATTERNS = tuple(p for p in itertools.product((0, -1, 1), repeat=3) if any(p))


def _ellipsoid(P, c, A):
    """Signed distances ``(B,)`` and outward normals ``(B, 3)`` of points ``P (B, 3)`` to
    ellipsoids ``(c (B, 3), A (B, 3, 3))`` (module docstring)."""
    a = c - P
    w, V = np.linalg.eigh(np.einsum("bki,bkj->bij", A, A))  # AᵀA, ascending
    b = np.einsum("bki,bk->bi", V, np.einsum("bki,bk->bi", A, a))  # Vᵀ Aᵀ a
    # bisect μ = λ + w_min on (0, |b|]: w + λ = (w − w_min) + μ keeps its relative
    # precision near the pole (a point near the medial surface inside)
    gap = w - w[:, :1]
    lo = np.zeros(len(P))
    hi = np.linalg.norm(b, axis=1)
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            phi = np.sum((b / (gap + mid[:, None])) ** 2, axis=1) - 1.0
        above = ~(phi <= 0.0)  # NaN/inf at the pole: still left of the root
        lo = np.where(above, mid, lo)
        hi = np.where(above, hi, mid)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = -b / (gap + hi[:, None])  # s in the eigenbasis; hi: |s| ≤ 1 side of the root
    z = np.where(np.isfinite(z), z, 0.0)
    # the hard case: |s| < 1 at the pole; the rest of the length along the smallest axis (a
    # shortfall at round-off level is the bisection's last interval, and normalising fixes it)
    short = 1.0 - np.sum(z * z, axis=1)
    short = np.where(short > 1e-10, short, 0.0)
    z[:, 0] += np.sqrt(short) * np.where(z[:, 0] < 0, -1.0, 1.0)
    s = np.einsum("bij,bj->bi", V, z)
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    q = c + np.einsum("bij,bj->bi", A, s)
    Ainv = np.linalg.inv(A)
    nrm = np.einsum("bji,bj->bi", Ainv, s)  # A⁻ᵀ s
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    sp = np.einsum("bij,bj->bi", Ainv, P - c)
    sign = np.where(np.sum(sp * sp, axis=1) > 1.0, 1.0, -1.0)
    return sign * np.linalg.norm(P - q, axis=1), nrm


def _box(P, c, A):
    """Signed distances ``(B,)`` and outward normals ``(B, 3)`` of points ``P (B, 3)`` to
    parallelepipeds ``(c (B, 3), A (B, 3, 3))`` (module docstring)."""
    a = c - P
    Ainv = np.linalg.inv(A)
    sp = np.einsum("bij,bj->bi", Ainv, P - c)
    rows = np.linalg.norm(Ainv, axis=2)  # |A⁻ᵀ e_k| = |row k of A⁻¹|
    # inside: the nearest face plane
    face = (1.0 - np.abs(sp)) / rows
    k = np.argmin(face, axis=1)
    ar = np.arange(len(P))
    d_in = -face[ar, k]
    n_in = np.sign(sp[ar, k])[:, None] * Ainv[ar, k] / rows[ar, k][:, None]
    # outside: the best feasible active set of min |a + A s|², |s_i| <= 1
    best = np.full(len(P), np.inf)
    y_best = np.zeros_like(P)
    for pat in _PATTERNS:
        s = np.broadcast_to(np.array(pat, dtype=np.float64), P.shape).copy()
        free = np.array([v == 0 for v in pat])
        if free.any():
            Mf = A[:, :, free]
            r = a + np.einsum("bij,bj->bi", A[:, :, ~free], s[:, ~free])
            G = np.einsum("bki,bkj->bij", Mf, Mf)
            sol = -np.linalg.solve(G, np.einsum("bki,bk->bi", Mf, r)[..., None])[..., 0]
            s[:, free] = sol
            ok = np.all(np.abs(sol) <= 1.0 + 1e-12, axis=1)
        else:
            ok = np.ones(len(P), dtype=bool)
        y = a + np.einsum("bij,bj->bi", A, s)
        val = np.where(ok, np.sum(y * y, axis=1), np.inf)
        better = val < best
        best = np.where(better, val, best)
        y_best[better] = y[better]
    d_out = np.sqrt(best)
    outside = np.abs(sp).max(axis=1) > 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        n_out = -y_best / d_out[:, None]
    n_out = np.where(np.isfinite(n_out) & (d_out[:, None] > 0), n_out, n_in)
    return np.where(outside, d_out, d_in), np.where(outside[:, None], n_out, n_in)


def _signed(P, kinds, centres, shapes):
    """``(d (B,), n (B, 3))`` of rows ``P (B, 3)`` against bodies of ``kinds (B,)`` (bool:
    ellipsoid) with ``centres (B, 3)``, ``shapes (B, 3, 3)``, each kind in one batch."""
    d, n = np.empty(len(P)), np.empty_like(P)
    for mask, fn in ((kinds, _ellipsoid), (~kinds, _box)):
        if mask.any():
            d[mask], n[mask] = fn(P[mask], centres[mask], shapes[mask])
    return d, n


def body_signed_distance(points, body: ConvexBody):
    """Signed distance of 3-D points to a convex body, and its gradient (module docstring).

    Parameters
    ----------
    points : array_like
        ``(n, 3)`` points.
    body : ConvexBody
        An ellipsoid or a parallelepiped.

    Returns
    -------
    d : numpy.ndarray
        ``(n,)`` Euclidean signed distances (negative inside).
    normal : numpy.ndarray
        ``(n, 3)`` ``∇d``: the outward unit normal at the nearest boundary point.
    """
    if not isinstance(body, ConvexBody):
        raise InvalidInputError(f"body: expected a ConvexBody, got {type(body).__name__}")
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(P)
    kinds = np.full(n, body.kind == "ellipsoid")
    return _signed(
        P, kinds, np.broadcast_to(body.centre, (n, 3)), np.broadcast_to(body.A, (n, 3, 3))
    )


def obstacle_barrier_3d(points, bodies, weight: float, scale: float):
    """The barrier ``Σ_j Σ_O w exp(−d_O(p_j)/δ)`` of 3-D points against convex bodies, with
    its gradient and Gauss–Newton Hessian (module docstring).

    Parameters
    ----------
    points : array_like
        ``(n, 3)`` points ``p_j``.
    bodies : sequence of ConvexBody
        The obstacles.
    weight : float
        ``w ≥ 0`` (the cost at ``d = 0``).
    scale : float
        ``δ > 0``, the decay length.

    Returns
    -------
    value : float
        The barrier.
    grad : numpy.ndarray
        ``(n, 3)``, ``Σ_O φ'(d_O) n_O`` per point.
    hess : numpy.ndarray
        ``(n, 3, 3)``, ``Σ_O φ''(d_O) n_O n_Oᵀ`` per point (positive semi-definite).
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    _check_weights(weight, scale)
    value, grad, hess = 0.0, np.zeros_like(P), np.zeros((len(P), 3, 3))
    for body in bodies:
        d, n = body_signed_distance(P, body)
        phi = weight * np.exp(-d / scale)
        value += float(phi.sum())
        grad += (-phi / scale)[:, None] * n
        hess += (phi / scale**2)[:, None, None] * n[:, :, None] * n[:, None, :]
    return value, grad, hess


def _check_weights(weight, scale):
    if not (np.isfinite(scale) and scale > 0 and np.isfinite(weight) and weight >= 0):
        raise InvalidInputError(
            f"barrier: expected weight >= 0 and scale > 0, got {weight}, {scale}"
        )


@dataclass(frozen=True, eq=False)
class _Barrier3D:
    """The 3-D obstacle term over a trajectory (the 2-D ``_Barrier`` of
    :mod:`riskplan.control.ilqr_cost` with convex bodies): one row per (step ``t ≥ 1``,
    checked point ``j``, body), the point ``base[t][j] + W[t][j] (x_t[col] − x*_t[col])``;
    ``col (k, 3)`` the reduced state's indices of the collision points."""

    steps: np.ndarray  # (R,) step of each row
    W: np.ndarray  # (R, k) weights of the row's point
    base: np.ndarray  # (R, 3)
    kinds: np.ndarray  # (R,) bool: ellipsoid
    centres: np.ndarray  # (R, 3)
    shapes: np.ndarray  # (R, 3, 3)
    col: np.ndarray
    ref: np.ndarray
    weight: float
    scale: float

    def terms(self, x, derivatives: bool = True):
        """``(value, b_x (T + 1, p), b_xx (T + 1, p, p))`` along ``x (T + 1, p)`` (zero at
        ``t = 0``); the value alone with ``derivatives=False``."""
        Tp1, p = x.shape
        k = len(self.col)
        flat = self.col.reshape(-1)
        if len(self.steps) == 0:
            return 0.0 if not derivatives else (0.0, np.zeros((Tp1, p)), np.zeros((Tp1, p, p)))
        dev = (x[:, self.col] - self.ref[:, self.col])[self.steps]  # (R, k, 3)
        pts = self.base + np.einsum("rk,rki->ri", self.W, dev)
        d, nrm = _signed(pts, self.kinds, self.centres, self.shapes)
        phi = self.weight * np.exp(-d / self.scale)
        total = float(phi.sum())
        if not derivatives:
            return total
        g = (-phi / self.scale)[:, None] * nrm  # (R, 3)
        h = (phi / self.scale**2)[:, None, None] * nrm[:, :, None] * nrm[:, None, :]
        gc = np.einsum("ra,ri->rai", self.W, g).reshape(-1, 3 * k)
        hc = np.einsum("ra,rc,rij->raicj", self.W, self.W, h).reshape(-1, 3 * k, 3 * k)
        gt, ht = np.zeros((Tp1, 3 * k)), np.zeros((Tp1, 3 * k, 3 * k))
        np.add.at(gt, self.steps, gc)
        np.add.at(ht, self.steps, hc)
        bx, bxx = np.zeros((Tp1, p)), np.zeros((Tp1, p, p))
        bx[:, flat] = gt
        bxx[:, flat[:, None], flat[None, :]] = ht
        return total, bx, bxx


def make_barrier_3d(plan: NominalPlan, obstacles, points, body, weight, scale) -> _Barrier3D:
    """The 3-D barrier of :func:`~riskplan.control.ilqr.ilqr`'s arguments, checked:
    ``T + 1`` steps of :class:`~riskplan.geometry3d.ConvexBody` lists, point indices
    ``(k, 3)`` inside the reduced state, ``T + 1`` body steps ``(base (n, 3), W (n, k))``
    (default the collision points themselves), ``w ≥ 0``, ``δ > 0``."""
    T, p = plan.n_steps, plan.reduced.shape[1]
    obstacles = [list(step) for step in obstacles]
    idx = np.asarray(points, dtype=np.int64)
    if idx.ndim != 2 or idx.shape[1] != 3:
        raise InvalidInputError(
            f"points: expected (k, 3) indices for 3-D obstacles, got shape {idx.shape}"
        )
    if len(obstacles) != T + 1 or idx.min() < 0 or idx.max() >= p:
        raise InvalidInputError(
            f"obstacles/points: expected {T + 1} steps of bodies and indices in [0, {p})"
        )
    if not all(isinstance(o, ConvexBody) for step in obstacles for o in step):
        raise InvalidInputError("obstacles: expected ConvexBody entries in every step")
    k = len(idx)
    if body is None:
        body = [(plan.reduced[t][idx], np.eye(k)) for t in range(T + 1)]
    if len(body) != T + 1:
        raise InvalidInputError(f"body: expected {T + 1} steps, got {len(body)}")
    _check_weights(weight, scale)
    rows = []
    for t in range(1, T + 1):
        b = np.asarray(body[t][0], dtype=np.float64).reshape(-1, 3)
        Wt = np.asarray(body[t][1], dtype=np.float64).reshape(len(b), k)
        rows += [(t, b[j], Wt[j], o) for j in range(len(b)) for o in obstacles[t]]
    return _Barrier3D(
        steps=np.array([r[0] for r in rows], dtype=np.int64),
        W=np.array([r[2] for r in rows]).reshape(-1, k),
        base=np.array([r[1] for r in rows]).reshape(-1, 3),
        kinds=np.array([r[3].kind == "ellipsoid" for r in rows], dtype=bool),
        centres=np.array([r[3].centre for r in rows]).reshape(-1, 3),
        shapes=np.array([r[3].A for r in rows]).reshape(-1, 3, 3),
        col=idx,
        ref=np.asarray(plan.reduced, dtype=np.float64),
        weight=float(weight),
        scale=float(scale),
    )


def scenario_terms_3d(
    sim,
    plan: NominalPlan,
    *,
    goal_weight: float,
    barrier_weight: float,
    barrier_scale: float,
) -> dict:
    """The goal and obstacle terms of :func:`~riskplan.control.ilqr.ilqr` read from a 3-D
    scenario (``workspace_dim = 3``, the 3-D needle), as the 2-D
    ``scenario_terms`` (:mod:`riskplan.control.ilqr_cost`) reads a 2-D one:

    * goal ``g``: ``x*_T`` with the tip ``x[0:3]`` moved to the centre of the target at
      ``y*_T`` (``state_goal``: the deformed ellipsoid in the world frame),
      ``Q_goal = goal_weight / r² I₃`` on the tip, ``r = |det A|^{1/3}`` the radius of the
      ball of the deformed target's volume;
    * obstacles of every step ``t``: ``state_obstacles(y*_t)`` (the deformed bodies the
      collision test uses), checked at the tip, ``w = barrier_weight``,
      ``δ = barrier_scale ×`` the mean Bryson scale of the tip (``sim.state_scale[:3]``,
      the target radius).

    Parameters
    ----------
    sim : Simulator
        A 3-D scenario.
    plan : NominalPlan
        The reference plan.
    goal_weight, barrier_weight, barrier_scale : float
        As the 2-D terms' (their defaults are ``GOAL_WEIGHT``, ``BARRIER_WEIGHT``,
        ``BARRIER_SCALE`` of :mod:`riskplan.control.ilqr_cost`, whose ``scenario_terms``
        hands a 3-D scenario here).

    Returns
    -------
    dict
        Keyword arguments of :func:`~riskplan.control.ilqr.ilqr`: ``goal``, ``Q_goal``,
        ``obstacles``, ``points``, ``barrier_weight``, ``barrier_scale``.
    """
    gidx = list(getattr(sim, "goal_point_indices", (0, 1, 2)))
    p = plan.reduced.shape[1]
    target = sim.state_goal(plan.states[-1])
    r = float(abs(np.linalg.det(target.A)) ** (1.0 / 3.0))
    goal = np.array(plan.reduced[-1], dtype=np.float64)
    goal[gidx] = target.centre
    Qg = np.zeros((p, p))
    Qg[gidx, gidx] = goal_weight / r**2
    scale = getattr(sim, "state_scale", None)
    unit = 1.0 if scale is None else float(np.mean(np.asarray(scale)[gidx]))
    return dict(
        goal=goal,
        Q_goal=Qg,
        obstacles=[list(sim.state_obstacles(y)) for y in plan.states],
        points=(tuple(gidx),),
        barrier_weight=float(barrier_weight),
        barrier_scale=float(barrier_scale) * unit,
    )
