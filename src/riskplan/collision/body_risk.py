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

from riskplan._validation import check_counts
from riskplan.collision.environment import Environment, check_environment
from riskplan.collision.mixture_bounds import check_mixture
from riskplan.errors import InvalidInputError

__all__ = [
    "DEFAULT_EXTENT",
    "CloudRisk",
    "allocate_points",
    "cloud_risk",
    "sampled_body_gaps",
    "sampled_body_risk",
    "sphere_directions",
]

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
    """Points per component ``(..., K)`` summing to ``n``: ``n w_k`` rounded by largest remainders.

    Parameters
    ----------
    weights : array_like, shape (..., K)
        Mixture weights, summing to 1.
    n : int
        Points to allocate.

    Returns
    -------
    numpy.ndarray
        ``(..., K)`` int64 counts.
    """
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
    mixture : GaussianMixture or NumpyMixture
        ``T`` mixtures (``weights (T, K)``, ``means (T, K, 3)``, ``precision_cholesky
        (T, K, 3, 3)``) along a trajectory, or one mixture (``T = 1``); base frame of
        ``environment``.
    environment : Environment
        Obstacles (3-D, or 2-D with 2-D mixtures).
    n_points : int
        Points per cloud (the point clouds the MDN learned from have 512).
    n_clouds : int
        Clouds (executions) drawn; the same ``seed`` gives the same draws for every call
        (common random numbers: a deterministic function of the mixtures).
    coherence : float
        ``ρ`` in ``[0, 1]``.
    margin : float
        A point counts as touching when its signed distance is below ``margin`` [m] (``0``:
        inside).
    seed : int
        Seeds the draws.
    validate : bool
        Check the inputs.

    Returns
    -------
    CloudRisk
        Per-configuration and trajectory fractions of colliding clouds, and the hits.
    """
    env = check_environment(environment) if validate else environment
    gm = check_mixture(mixture, env.dim, validate=validate)
    if validate:
        check_counts({"n_points": n_points, "n_clouds": n_clouds}, 1)
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
            # inside-or-not needs only the winding number, several times cheaper than distances
            inside = env.contains(P) if margin == 0 else env.signed_distance(P) < margin
            hits[:, t] = inside.any(axis=1)
    return CloudRisk(hits.mean(axis=0), float(hits.any(axis=1).mean()), hits)


#: a component's body piece reaches this many of its (surface) standard deviations from its
#: mean: a uniform flat disk of radius ``R`` has in-plane standard deviation ``R / 2``, and the
#: separator disks are the parts of the body that reach obstacles (they stand 7 mm proud of the
#: 3 mm backbone); docs/validation.md gives the sensitivity to it
DEFAULT_EXTENT = 2.0


def sphere_directions(n: int) -> np.ndarray:
    """Unit vectors spread evenly over the sphere (Fibonacci lattice, deterministic).

    Parameters
    ----------
    n : int
        Number of directions.

    Returns
    -------
    numpy.ndarray
        ``(n, 3)`` unit vectors; the first is nearest ``+z`` (``z = 1 - 1/n``).
    """
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def _check_drawn_bodies(env, D: np.ndarray, shape: tuple, extent, what: str) -> None:
    """The checks of the sampled bodies' inputs: 3-D obstacles, ``drawn_means (S >= 2,
    *shape)`` finite, and a finite ``extent > 0``; ``what`` names the caller."""
    if env.dim != 3:
        raise InvalidInputError(f"environment: {what} needs 3-D obstacles")
    if D.ndim != 4 or D.shape[1:] != shape or D.shape[0] < 2:
        T, K, d = shape
        raise InvalidInputError(
            f"drawn_means: expected shape (S >= 2, {T}, {K}, {d}), got {D.shape}"
        )
    if not np.all(np.isfinite(D)):
        raise InvalidInputError("drawn_means: expected finite values")
    if not (np.isfinite(extent) and extent > 0):
        raise InvalidInputError(f"extent: expected a finite number > 0, got {extent!r}")


def sampled_body_risk(
    nominal,
    drawn_means,
    environment: Environment,
    *,
    extent: float = DEFAULT_EXTENT,
    n_points: int = 512,
    n_directions: int = 256,
    validate: bool = True,
) -> CloudRisk:
    r"""Probability that the body touches an obstacle, as a mixture over sampled whole bodies.

    One sample is one execution: the transmission's draw (start history, play, offset) gives
    the configuration the robot really receives, ``d + δ_s``, and the learned model's
    component means there, ``μ_k(d + δ_s)``, place every body piece of that execution at once
    (the whole backbone moves together). A component's *surface* spread is its predicted
    covariance without the part the executions produce,

    .. math::

        \Sigma^{\rm body}_k = \Big[\Sigma_k(d) - \mathrm{Cov}_s\, \mu_k(d + \delta_s)\Big]_+

    (negative eigenvalues set to 0), and its body piece is the ellipsoid
    ``E_{ks} = {μ_k(d + δ_s) + c L_k u : |u| <= 1}`` with ``L_k L_k^T = Σ^body_k`` and
    ``c = extent``. Execution ``s`` collides at configuration ``t`` when one of its pieces meets
    an obstacle; the risk per configuration is the fraction of colliding samples, and along a
    trajectory the fraction colliding at some configuration (each sample keeps its draw):

    .. math:: P(\tau) = \frac{1}{S} \sum_s \mathbf 1\big[\exists t, k:\ E_{kst} \cap \mathcal O \ne \emptyset\big].

    Components that would not hold one of ``n_points`` points (``w_k n_points < 1``, the
    rounding of :func:`allocate_points`) are not body. A piece meets an obstacle when its centre
    or one of ``n_directions`` points of its boundary (:func:`sphere_directions`) lies inside
    an obstacle; pieces whose centre is farther than their largest semi-axis are skipped.

    Parameters
    ----------
    nominal : mixture
        Mixtures at the commanded configurations, batch ``(T,)``: ``weights (T, K)``,
        ``means (T, K, 3)``, ``precision_cholesky (T, K, 3, 3)`` (or one mixture, ``T = 1``).
    drawn_means : array_like
        ``(S, T, K, 3)`` component means at the configurations the ``S >= 2`` executions
        receive (the same component order).
    environment : Environment
        3-D obstacles in the frame of the mixtures.
    extent : float
        ``c`` above (> 0).
    n_points : int
        Points of a body cloud (decides which components are body).
    n_directions : int
        Boundary points tested per piece.
    validate : bool
        Check the inputs (False: trusted).

    Returns
    -------
    CloudRisk
        ``per_configuration (T,)``, ``trajectory`` and ``hits (S, T)``.
    """
    env = check_environment(environment) if validate else environment
    gm = check_mixture(nominal, env.dim, validate=validate)
    W = gm.weights.reshape(-1, gm.weights.shape[-1])
    M = gm.means.reshape(-1, *gm.means.shape[-2:])
    U = gm.precision_cholesky.reshape(-1, *gm.precision_cholesky.shape[-3:])
    T, K, d = M.shape
    D = np.asarray(drawn_means, dtype=np.float64)
    if validate:
        _check_drawn_bodies(env, D, (T, K, d), extent, "sampled_body_risk")
        check_counts({"n_points": n_points, "n_directions": n_directions}, 1)
    S = D.shape[0]
    semi, axes, active = _body_pieces(W, U, D, extent, n_points)
    dirs = sphere_directions(int(n_directions))
    hits = np.zeros((S, T), dtype=bool)
    for t in range(T):
        ks = np.nonzero(active[t])[0]
        C = D[:, t, ks]  # (S, k, 3)
        sd = env.signed_distance(C)  # (S, k)
        hit = (sd < 0).any(axis=1)
        reach = semi[t, ks].max(axis=-1)  # (k,)
        s_idx, j = np.nonzero((sd >= 0) & (sd < reach[None]))
        if len(s_idx):
            P = C[s_idx, j][:, None, :] + dirs @ np.swapaxes(axes[t, ks[j]], -1, -2)
            touch = env.contains(P).any(axis=1)
            np.logical_or.at(hit, s_idx[touch], True)
        hits[:, t] = hit
    return CloudRisk(hits.mean(axis=0), float(hits.any(axis=1).mean()), hits)


def _body_pieces(W, U, D, extent, n_points):
    """Semi-axes ``(T, K, 3)``, semi-axis vectors ``(T, K, 3, 3)`` (columns) and the body
    components ``(T, K)`` of :func:`sampled_body_risk` (its docstring has the law)."""
    S = D.shape[0]
    L = np.linalg.inv(U)
    sigma = L @ np.swapaxes(L, -1, -2)  # (T, K, 3, 3)
    dev = D - D.mean(axis=0)
    execution = np.einsum("stki,stkj->tkij", dev, dev) / (S - 1)
    lam, V = np.linalg.eigh(sigma - execution)
    semi = extent * np.sqrt(np.clip(lam, 0.0, None))  # (T, K, 3) semi-axes
    axes = V * semi[..., None, :]  # columns: the ellipsoid's semi-axis vectors
    active = allocate_points(W, n_points) > 0  # (T, K)
    return semi, axes, active


def sampled_body_gaps(
    nominal,
    drawn_means,
    environment: Environment,
    *,
    extent: float = DEFAULT_EXTENT,
    n_points: int = 512,
    validate: bool = True,
) -> np.ndarray:
    r"""Clearance of each sampled body of :func:`sampled_body_risk`, per execution and configuration.

    For execution ``s`` at configuration ``t`` the smallest, over its body pieces ``k``
    (the ellipsoids ``E_{kst}`` of :func:`sampled_body_risk`), of the piece's clearance in the
    tangent-plane approximation

    .. math:: g_{st} = \min_k \Big[\, \mathrm{sd}(\mu_{kst}) - \lVert A_k^\top n_{kst} \rVert \Big],

    with ``sd`` the signed distance of the piece's centre to the obstacles (negative inside),
    ``n`` the unit direction from the closest obstacle point to the centre and ``A_k`` the
    piece's semi-axis vectors (``‖A^T n‖`` is the ellipsoid's reach along ``n``): exact when
    the obstacle is a half-space there, otherwise a signed distance of the body that is
    negative whenever the piece's centre is inside. ``g < 0`` is the tangent-plane version of
    :func:`sampled_body_risk`'s collision decision; the distribution of ``g`` over the
    executions is what a calibrated map (docs/validation.md) turns into a risk.

    Parameters
    ----------
    nominal, drawn_means, environment, extent, n_points, validate
        As in :func:`sampled_body_risk`.

    Returns
    -------
    numpy.ndarray
        ``(S, T)`` clearances [m] (``inf`` where no component is body).
    """
    env = check_environment(environment) if validate else environment
    gm = check_mixture(nominal, env.dim, validate=validate)
    W = gm.weights.reshape(-1, gm.weights.shape[-1])
    U = gm.precision_cholesky.reshape(-1, *gm.precision_cholesky.shape[-3:])
    T, K = W.shape
    D = np.asarray(drawn_means, dtype=np.float64)
    if validate:
        _check_drawn_bodies(env, D, (T, K, 3), extent, "sampled_body_gaps")
    S = D.shape[0]
    _, axes, active = _body_pieces(W, U, D, extent, n_points)
    gaps = np.full((S, T), np.inf)
    for t in range(T):
        ks = np.nonzero(active[t])[0]
        if not len(ks):
            continue
        C = D[:, t, ks]  # (S, k, 3)
        dist, closest, _ = env.closest_points(C)
        sd = np.where(env.contains(C), -dist, dist)
        n = (C - closest) / np.maximum(dist, 1e-12)[..., None]  # (S, k, 3), unit (sign free)
        reach = np.linalg.norm(np.einsum("kij,ski->skj", axes[t, ks], n), axis=-1)
        gaps[:, t] = (sd - reach).min(axis=1)
    return gaps
