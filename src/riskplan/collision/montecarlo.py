"""Monte Carlo reference for the collision bounds (seeded), with binomial confidence intervals.

* :func:`monte_carlo_probability` — a mixture batch ``(...)``: draw points and count those
  inside obstacles. ``combine="weighted"`` draws from the mixture (the quantity bounded by
  eq. 9); ``combine="union"`` draws one point from every component per trial and counts a
  trial as a collision if any is inside (the quantity bounded by the union variant).
* :func:`monte_carlo_trajectory` — mixtures ``(..., T)``: per trial one draw per state,
  independent across states (the model behind eq. 10); optionally the segments between
  consecutive draws are checked too.
* :func:`paths_collide` — caller-supplied sample paths ``(..., T, d)`` (e.g. correlated
  LQG-MP state samples): points inside obstacles and segments crossing them.
* :func:`binomial_interval` — Wilson score or Clopper-Pearson (exact) interval.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_generator
from riskplan.collision.environment import Environment, check_environment
from riskplan.collision.mixture_bounds import COMBINES, check_mixture
from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import NumpyMixture, draw_components

INTERVALS = ("wilson", "clopper-pearson")
# points per chunk (bounds memory at about 100 MB of float64 temporaries)
CHUNK = 1 << 18


@dataclass(frozen=True)
class MonteCarloEstimate:
    """``hits`` collisions in ``n`` trials; ``probability = hits / n`` and its interval ``[low, high]``
    at ``confidence`` (all arrays ``(...,)``)."""

    probability: np.ndarray
    low: np.ndarray
    high: np.ndarray
    hits: np.ndarray
    n: int
    confidence: float
    method: str


def binomial_interval(
    hits, n: int, confidence: float = 0.95, method: str = "wilson"
) -> tuple[np.ndarray, np.ndarray]:
    r"""Two-sided ``confidence`` interval for a binomial proportion ``hits / n``.

    ``wilson``: the Wilson score interval, vectorised over ``hits``,

    .. math::

        \frac{\hat p + \frac{z^2}{2n} \pm z \sqrt{\frac{\hat p (1 - \hat p)}{n} +
        \frac{z^2}{4 n^2}}}{1 + \frac{z^2}{n}}, \qquad \hat p = k / n,
        \quad z = \Phi^{-1}(1 - \alpha / 2)

    (the same numbers as ``scipy.stats.binomtest(k, n).proportion_ci(method="wilson")``,
    which the tests use as the oracle). ``clopper-pearson``: the exact interval from Beta
    quantiles (never below nominal coverage).

    Parameters
    ----------
    hits : array_like of int
        Successes ``k``, each in ``[0, n]``.
    n : int
        Trials (> 0).
    confidence : float
        Level in ``(0, 1)``.
    method : {"wilson", "clopper-pearson"}
        The interval.

    Returns
    -------
    low, high : numpy.ndarray
        Bounds of the interval, the shape of ``hits``.
    """
    from scipy.special import betaincinv, ndtri

    k = np.asarray(hits, dtype=np.float64)
    if n <= 0:
        raise InvalidInputError(f"n: expected > 0 trials, got {n}")
    if np.any((k < 0) | (k > n)):
        raise InvalidInputError("hits: must lie in [0, n]")
    if not (0 < confidence < 1):
        raise InvalidInputError(f"confidence: expected in (0, 1), got {confidence}")
    alpha = 1.0 - confidence
    if method == "wilson":
        z = ndtri(1 - alpha / 2)
        p = k / n
        den = 1 + z * z / n
        centre = (p + z * z / (2 * n)) / den
        half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
        low, high = centre - half, centre + half
        low = np.where(k == 0, 0.0, low)
        high = np.where(k == n, 1.0, high)
    elif method == "clopper-pearson":
        with np.errstate(invalid="ignore"):
            low = np.where(k == 0, 0.0, betaincinv(k, n - k + 1, alpha / 2))
            high = np.where(k == n, 1.0, betaincinv(k + 1, n - k, 1 - alpha / 2))
    else:
        raise InvalidInputError(f"method: expected one of {INTERVALS}, got {method!r}")
    return np.clip(low, 0.0, 1.0), np.clip(high, 0.0, 1.0)


def _flat_parameters(gm: NumpyMixture) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``weights (B, K)``, ``means (B, K, d)`` and ``U^{-1} (B, K, d, d)`` over the flattened batch."""
    K, d = gm.n_components, gm.dim
    return (
        gm.weights.reshape(-1, K),
        gm.means.reshape(-1, K, d),
        np.linalg.inv(gm.precision_cholesky.reshape(-1, K, d, d)),
    )


def _check_n(n_samples) -> int:
    n = int(n_samples)
    if n <= 0:
        raise InvalidInputError(f"n_samples: expected > 0, got {n_samples}")
    return n


def _estimate(hits, n: int, shape, confidence: float, interval: str) -> MonteCarloEstimate:
    """Binomial estimate with its interval from ``hits (B,)`` out of ``n``, reshaped to ``shape``."""
    low, high = binomial_interval(hits, n, confidence, interval)
    return MonteCarloEstimate(
        probability=(hits / n).reshape(shape),
        low=low.reshape(shape),
        high=high.reshape(shape),
        hits=hits.reshape(shape),
        n=n,
        confidence=confidence,
        method=interval,
    )


def monte_carlo_probability(
    mixture,
    environment: Environment,
    n_samples: int = 10_000,
    *,
    combine: str = "weighted",
    seed=None,
    confidence: float = 0.95,
    interval: str = "wilson",
    validate: bool = True,
) -> MonteCarloEstimate:
    """Estimate the collision probability of a mixture batch by sampling.

    ``combine="weighted"``: fraction of points drawn from the mixture that lie inside obstacles
    (what eq. 9 bounds). ``combine="union"``: fraction of trials in which at least one of K
    points, one per component drawn independently, lies inside (what the union bound bounds).

    Parameters
    ----------
    mixture : NumpyMixture or GaussianMixture
        Batch shape ``(...)``, ``K`` components in ``d`` dimensions.
    environment : Environment
        Obstacles of dimension ``d``.
    n_samples : int
        Trials per mixture.
    combine : str
        ``"weighted"`` or ``"union"``.
    seed : int, numpy.random.Generator or None
        Seed of the draws.
    confidence : float
        Two-sided confidence of the interval, in (0, 1).
    interval : str
        ``"wilson"`` or ``"clopper-pearson"`` (:func:`binomial_interval`).
    validate : bool
        Check the mixture's shapes and values.

    Returns
    -------
    MonteCarloEstimate
        ``probability``, ``low``, ``high`` and ``hits``, each ``(...,)``.
    """
    if combine not in COMBINES:
        raise InvalidInputError(f"combine: expected one of {COMBINES}, got {combine!r}")
    n = _check_n(n_samples)
    check_environment(environment)
    gm = check_mixture(mixture, environment.dim, validate=validate)
    shape = gm.batch_shape
    w, m, uinv = _flat_parameters(gm)
    rng = as_generator(seed)
    hits = np.zeros(w.shape[0], dtype=np.int64)
    per = max(1, CHUNK // (w.shape[0] * (gm.n_components if combine == "union" else 1)))
    done = 0
    while done < n:
        c = min(per, n - done)
        x = draw_components(rng, w, m, uinv, c, one_per_component=combine == "union")
        inside = environment.contains(x).any(-1)  # (B, c)
        hits += inside.sum(-1)
        done += c
    return _estimate(hits, n, shape, confidence, interval)


def paths_collide(paths, environment: Environment, *, segments: bool = True) -> np.ndarray:
    """Whether each path has a point inside an obstacle or (``segments``) a segment crossing one.

    Parameters
    ----------
    paths : array_like, (..., T, d)
        ``T`` points per path.
    environment : Environment
        Obstacles of dimension ``d``.
    segments : bool
        Also check the straight segments between consecutive points.

    Returns
    -------
    numpy.ndarray of bool, (...,)
    """
    x = np.asarray(paths, dtype=np.float64)
    d = check_environment(environment).dim
    if x.ndim < 2 or x.shape[-1] != d:
        raise InvalidInputError(f"paths: expected shape (..., T, {d}), got {x.shape}")
    hit = environment.contains(x).any(-1)
    if segments and x.shape[-2] > 1:
        hit = hit | environment.segments_collide(x[..., :-1, :], x[..., 1:, :]).any(-1)
    return hit


def monte_carlo_trajectory(
    mixtures,
    environment: Environment,
    n_samples: int = 10_000,
    *,
    combine: str = "weighted",
    segments: bool = False,
    seed=None,
    confidence: float = 0.95,
    interval: str = "wilson",
    validate: bool = True,
) -> MonteCarloEstimate:
    """Estimate ``P(exists t: x_t in collision)`` for a batch of trajectories of mixtures.

    Each trial draws every state independently (``combine`` as in
    :func:`monte_carlo_probability`); with ``segments`` the straight segments between
    consecutive draws are checked as well.

    Parameters
    ----------
    mixtures : NumpyMixture or GaussianMixture
        Batch shape ``(..., T)``: ``T`` states along each trajectory.
    environment : Environment
        Obstacles of the mixtures' dimension.
    n_samples : int
        Trials per trajectory.
    combine : str
        ``"weighted"`` or ``"union"``.
    segments : bool
        Also check the segments between consecutive draws.
    seed : int, numpy.random.Generator or None
        Seed of the draws.
    confidence : float
        Two-sided confidence of the interval.
    interval : str
        ``"wilson"`` or ``"clopper-pearson"``.
    validate : bool
        Check the mixtures' shapes and values.

    Returns
    -------
    MonteCarloEstimate
        Estimates of shape ``(...,)``.
    """
    if combine not in COMBINES:
        raise InvalidInputError(f"combine: expected one of {COMBINES}, got {combine!r}")
    n = _check_n(n_samples)
    check_environment(environment)
    gm = check_mixture(mixtures, environment.dim, validate=validate)
    if len(gm.batch_shape) < 1:
        raise InvalidInputError("mixtures: expected a batch axis of states (batch shape (..., T))")
    shape, T = gm.batch_shape[:-1], gm.batch_shape[-1]
    K, d = gm.n_components, gm.dim
    w, m, uinv = _flat_parameters(gm)
    B = w.shape[0] // T
    rng = as_generator(seed)
    hits = np.zeros(B, dtype=np.int64)
    S = K if combine == "union" else 1
    per = max(1, CHUNK // (w.shape[0] * S))
    done = 0
    while done < n:
        c = min(per, n - done)
        x = draw_components(rng, w, m, uinv, c, one_per_component=combine == "union")
        x = x.reshape(B, T, c, S, d)
        hit = environment.contains(x).any(-1).any(1)  # (B, c)
        if segments and T > 1:
            seg = environment.segments_collide(x[:, :-1], x[:, 1:])  # (B, T-1, c, S)
            hit = hit | seg.any(-1).any(1)
        hits += hit.sum(-1)
        done += c
    return _estimate(hits, n, shape, confidence, interval)
