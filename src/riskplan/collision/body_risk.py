"""Probability that the robot's body touches an obstacle, from the learned point density
(beyond the MDN paper; issue 18, item 11).

Eq. 9 bounds the probability that *one point* drawn from the predicted mixture lies inside an
obstacle: roughly the fraction of the body in collision. The robot collides when *any part* of
its body enters an obstacle, and across executions its parts move together (one execution's
transmission variation bends the whole backbone). The MDN predicts only the marginal density
of a body point, so the joint law of the points of one body is a modelling choice. We take a
Gaussian copula with one shared draw per execution:

.. math::

    x_{si} = \\mu_{k(i)} + L_{k(i)} \\left(\\sqrt{\\rho}\\, z_s + \\sqrt{1 - \\rho}\\, \\varepsilon_{si}\\right),
    \\qquad z_s, \\varepsilon_{si} \\sim \\mathcal{N}(0, I_3),

for execution ``s`` and body point ``i`` of component ``k(i)`` (``L_k L_k^T = Σ_k``; the
``N`` points are split over the components in proportion to the weights). Each point keeps the
predicted marginal ``N(μ_k, Σ_k)``; ``ρ`` (the *coherence*) is the share of a component's
variance that moves the whole body at once (execution-to-execution variation) rather than
spreading points over its surface. ``ρ = 0``: independent points (a cloud of ``N`` independent
draws, which overstates the risk); ``ρ = 1``: the body is the component means shifted rigidly
(in each component's whitened frame) and its surface extent is lost. A cloud *collides* when
one of its points has a signed distance below ``margin`` (``0``: inside an obstacle); the risk
is the fraction of colliding clouds. Along a trajectory the same ``z_s`` is used at
every configuration (one execution keeps its transmission draw), so the trajectory risk is the
fraction of executions colliding at some configuration, not eq. 10's independence product.

Cost: components whose mean lies farther than ``6 max_eig(L_k)`` from every obstacle are skipped
(a point of them reaches an obstacle only if ``|w| > 6`` for a standard normal ``w`` in 3-D,
probability 1e-7), so only points near obstacles are tested.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan.collision.environment import Environment, check_environment
from riskplan.collision.mixture_bounds import check_mixture
from riskplan.errors import InvalidInputError

__all__ = ["CloudRisk", "allocate_points", "cloud_risk"]

#: a component farther than this many of its largest standard deviations is not sampled
CULL_SIGMAS = 6.0


@dataclass(frozen=True)
class CloudRisk:
    """Result of :func:`cloud_risk`: ``per_configuration (T,)``, ``trajectory`` (fraction of
    clouds colliding at some configuration) and ``hits (S, T)`` boolean."""

    per_configuration: np.ndarray
    trajectory: float
    hits: np.ndarray


def allocate_points(weights, n: int) -> np.ndarray:
    """Points per component ``(..., K)`` summing to ``n``: ``n w_k`` rounded by largest remainders."""
    w = np.asarray(weights, dtype=np.float64)
    raw = w * n
    base = np.floor(raw).astype(np.int64)
    short = n - base.sum(axis=-1, keepdims=True)
    order = np.argsort(-(raw - base), axis=-1, kind="stable")
    rank = np.argsort(order, axis=-1, kind="stable")
    return base + (rank < short).astype(np.int64)


def cloud_risk(
    mixture,
    environment: Environment,
    *,
    n_points: int = 512,
    n_clouds: int = 256,
    coherence: float = 0.9,
    margin: float = 0.0,
    seed: int = 0,
    validate: bool = True,
) -> CloudRisk:
    """Probability that a body cloud drawn from the mixtures touches an obstacle (module docstring).

    Parameters
    ----------
    mixture: ``T`` mixtures (``weights (T, K)``, ``means (T, K, 3)``, ``precision_cholesky
        (T, K, 3, 3)``) along a trajectory, or one mixture (``T = 1``); base frame of ``environment``.
    environment: obstacles (3-D, or 2-D with 2-D mixtures).
    n_points: points per cloud (the point clouds the MDN learned from have 512).
    n_clouds: clouds (executions) drawn; the same ``seed`` gives the same draws for every call
        (common random numbers: a deterministic function of the mixtures).
    coherence: ``ρ`` in ``[0, 1]``.
    margin: a point counts as touching when its signed distance is below ``margin`` [m]
        (``0``: inside).

    Returns
    -------
    :class:`CloudRisk`.
    """
    env = check_environment(environment) if validate else environment
    gm = check_mixture(mixture, env.dim, validate=validate)
    if validate:
        for name, v in (("n_points", n_points), ("n_clouds", n_clouds)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise InvalidInputError(f"{name}: expected a positive integer, got {v!r}")
        if not (np.isfinite(coherence) and 0.0 <= coherence <= 1.0):
            raise InvalidInputError(f"coherence: expected a number in [0, 1], got {coherence!r}")
        if not np.isfinite(margin):
            raise InvalidInputError(f"margin: expected a finite length, got {margin!r}")
    W = gm.weights.reshape(-1, gm.weights.shape[-1])
    M = gm.means.reshape(-1, *gm.means.shape[-2:])
    U = gm.precision_cholesky.reshape(-1, *gm.precision_cholesky.shape[-3:])
    T, K, d = M.shape
    L = np.linalg.inv(U)  # Σ = U^-1 U^-T, so L = U^-1 is a square root
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((n_clouds, d))
    eps = rng.standard_normal((n_clouds, n_points, d))
    a, b = np.sqrt(coherence), np.sqrt(1.0 - coherence)
    counts = allocate_points(W, n_points)  # (T, K)
    sig = np.linalg.norm(L, ord=2, axis=(-2, -1))  # (T, K) largest standard deviation
    near = env.signed_distance(M.reshape(-1, d)).reshape(T, K) < CULL_SIGMAS * sig + margin
    hits = np.zeros((n_clouds, T), dtype=bool)
    for t in range(T):
        start = np.concatenate([[0], np.cumsum(counts[t])])
        pts = []
        for k in np.nonzero(near[t] & (counts[t] > 0))[0]:
            w = a * z[:, None, :] + b * eps[:, start[k] : start[k + 1]]  # (S, n_k, d)
            pts.append(M[t, k] + w @ L[t, k].T)
        if pts:
            P = np.concatenate(pts, axis=1)  # (S, n_near, d)
            hits[:, t] = (env.signed_distance(P) < margin).any(axis=1)
    return CloudRisk(hits.mean(axis=0), float(hits.any(axis=1).mean()), hits)
