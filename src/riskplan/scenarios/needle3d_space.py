"""The 3-D needle's planning space (:class:`Needle3DSpace`) and its kinematic steering rule
(:func:`needle3d_steer`), which :meth:`riskplan.scenarios.needle3d.Needle3DScenario.planning_space`
hands the simulator RRT."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["needle3d_steer"]


@dataclass(frozen=True, eq=False)
class Needle3DSpace:
    """The 3-D needle's :class:`~riskplan.scenarios.space.PlanningSpace`.

    Samples: a position uniform in the block and an axis ``e₃`` uniform on the sphere
    (``e₁ = e₂ = 0``: the roll is not sampled). Metric (the 2-D needle's ``(x, y, r_min θ)``
    in 3-D)::

        d(x, x')² = |p − p'|² + (r ∠(e₃, e₃'))²

    with ``r = 1/κ`` (an axis error of 1 rad counts like the arc the needle needs to turn by
    it); towards the goal point the position only (any direction will do in the target).
    Valid: the position lies in the block.
    """

    size: np.ndarray
    goal: np.ndarray
    radius: float
    steer: object = None
    steps_per_extension: int = 6
    max_control_change: np.ndarray | None = None
    dim: int = 12

    def sample(self, gen: np.random.Generator, goal_bias: float = 0.0):
        u = gen.random(4)
        if u[-1] < goal_bias:
            return self.goal.copy(), True
        x = np.zeros(12)
        x[:3] = u[:3] * self.size
        a = gen.standard_normal(3)
        x[9:12] = a / np.linalg.norm(a)
        return x, False

    def distance(self, xs: np.ndarray, x: np.ndarray, *, to_goal: bool = False) -> np.ndarray:
        xs = np.asarray(xs, dtype=np.float64)
        dp = xs[:, :3] - x[:3]
        d2 = np.einsum("ij,ij->i", dp, dp)
        if not to_goal:
            c = np.clip(xs[:, 9:12] @ x[9:12], -1.0, 1.0)
            ang = np.arccos(c)
            d2 = d2 + (self.radius * ang) ** 2
        return np.sqrt(d2)

    def contains(self, x: np.ndarray) -> bool:
        return bool(np.all(x[:3] >= 0.0) and np.all(x[:3] <= self.size))


def needle3d_steer(x_from, x_to, bounds, n_steps: int, *, tau: float, kappa: float, duty: bool):
    """A control towards the point ``x_to[:3]`` (a candidate of the RRT's goal-directed
    extension): the best of a grid of constant controls — 5 speeds × 41 rotation rates (× 5
    curvature fractions with duty cycling) spanning ``bounds`` — by the nearest approach to
    the point of their exact kinematic paths over ``n_steps`` steps (the material frame,
    without the tissue; the bevel's motion has no closed-form two-point steering).

    Parameters
    ----------
    x_from : array_like, shape (12,)
        The pose vector steered from.
    x_to : array_like, shape (12,)
        The pose vector whose position ``x_to[:3]`` is steered towards.
    bounds : array_like, shape (q, 2)
        The control bounds.
    n_steps : int
        Steps of each candidate path.
    tau : float
        Step duration.
    kappa : float
        Needle curvature κ (1 / length).
    duty : bool
        Whether the control carries a duty-cycle fraction ρ (q = 3).

    Returns
    -------
    numpy.ndarray
        ``(q,)`` the chosen control.
    """
    p = np.asarray(x_from[:3], dtype=np.float64)
    R = np.asarray(x_from[3:12], dtype=np.float64).reshape(3, 3).T
    target = np.asarray(x_to[:3], dtype=np.float64)
    b = np.asarray(bounds, dtype=np.float64)
    U, D = _steer_paths(tuple(b.ravel().tolist()), b.shape[0], int(n_steps), tau, kappa, duty)
    # the paths in the start frame: p_k = p + R D_k (left invariance of the screw steps)
    best = np.linalg.norm(D @ R.T + (p - target), axis=2).min(axis=1)
    return U[int(np.argmin(best))].copy()


@functools.lru_cache(maxsize=16)
def _steer_paths(bounds: tuple, q: int, n_steps: int, tau: float, kappa: float, duty: bool):
    """``(U (n, q), D (n, n_steps, 3))``: :func:`needle3d_steer`'s grid of constant controls
    and the tip positions of their paths after 1 … ``n_steps`` steps, in the frame of the
    start (``D_1 = d``, ``D_{k+1} = D_k + E^k d`` with ``(E, d) = exp(τ ξ̂)``); the same for
    every start, so computed once per grid."""
    from riskplan.scenarios.bevel import se3_exp_batch

    b = np.asarray(bounds, dtype=np.float64).reshape(q, 2)
    lo, hi = b[:, 0], b[:, 1]
    vs = lo[0] + (hi[0] - lo[0]) * np.array([0.2, 0.4, 0.6, 0.8, 1.0])
    ws = np.linspace(lo[1], hi[1], 41)
    rhos = np.linspace(lo[2], hi[2], 5) if duty else np.array([1.0])
    V, Wg, P = (g.ravel() for g in np.meshgrid(vs, ws, rhos, indexing="ij"))
    xi = np.zeros((len(V), 6))
    xi[:, 2], xi[:, 3], xi[:, 5] = tau * V, tau * P * kappa * V, tau * Wg
    E, dd = se3_exp_batch(xi)
    D = np.empty((len(V), n_steps, 3))
    Rk = np.broadcast_to(np.eye(3), E.shape)
    pk = np.zeros_like(dd)
    for k in range(n_steps):
        pk = pk + np.einsum("nij,nj->ni", Rk, dd)
        Rk = Rk @ E
        D[:, k] = pk
    U = np.stack([V, Wg, P], axis=1)[:, :q]
    for a in (U, D):
        a.setflags(write=False)
    return U, D
