r"""Upper bound on the probability that a Gaussian point lies inside obstacles
(Patil, van den Berg, Alterovitz, ICRA 2012; MDN paper section V, eq. 8).

Method, per Gaussian ``N(mu, Sigma)`` with ``Sigma^{-1} = U^T U``:

1. Whiten the environment, ``E_hat = U (E - mu)`` (eq. 8): the Gaussian becomes ``N(0, I)``.
2. Take the obstacle point ``p`` closest to the origin, add the half-space ``a . y <= b`` with
   ``a = p / |p|``, ``b = |p|`` (tangent to the whitened obstacle at ``p``); discard every
   face lying entirely behind it; repeat until no face is left.
3. The intersection of the half-spaces is convex, contains the origin and meets no face, so
   (if the mean is in free space) it lies in free space, and

   .. math::

       \hat E = \bar U (E - \mu) \quad \text{(eq. 8)}, \qquad
       P(\text{collision}) \le P(y \notin \{a_j^\top y \le b_j\}) \le \sum_j (1 - \Phi(b_j)).

Faces (triangles or 2-D edges) are the convex pieces of the obstacles' surfaces.

Cut-off. Faces whose whitened distance is at least ``cutoff`` (default 9) are never visited;
the free region is then the polytope intersected with the ball ``|y| < cutoff``, so the
bound gains the exact chi-square tail ``P(|y| >= cutoff)`` (2.6e-17 in 3-D for 9), which keeps
it a valid upper bound while skipping the far faces. ``cutoff=inf`` runs the method exactly
as published.

Numerics. Every finite, valid input gives a number in [0, 1]: the kernel whitens in scaled
coordinates (``U / max|U|``, ``mu / max(1, |mu|)``), so precision factors from 1e-300 to 1e300
neither overflow nor underflow; a face whose whitened distance overflows contributes
``1 - Phi(inf) = 0``. Should a non-finite value still appear, :class:`InvalidInputError` is
raised instead of returning NaN (a NaN compares false against every threshold).

Means inside an obstacle (or on its surface): no convex free region around the mean
exists; the bound returns 1 for that Gaussian (always valid, and >= 0.5 as the closed form
for a point inside a half-space requires).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_array
from riskplan.collision import _kernels as K
from riskplan.collision.environment import Environment
from riskplan.errors import InvalidInputError

DEFAULT_CUTOFF = 9.0
# relative slack of the "entirely behind the half-space" test (whitened units)
BEHIND_EPS = 1e-9


def chi_tail(radius: float, d: int) -> float:
    """``P(|y| >= radius)`` for ``y ~ N(0, I_d)`` (chi distribution survival function)."""
    if not math.isfinite(radius):
        return 0.0
    from scipy.special import gammaincc

    return float(gammaincc(d / 2.0, radius * radius / 2.0))


@dataclass(frozen=True)
class GaussianBoundTerms:
    """Per-Gaussian pieces of the bound, for inspection (shapes ``(...,)``).

    ``bound = clip(halfspace_sum + tail, 0, 1)`` where the mean is free, and 1 where it is
    inside an obstacle or on its surface.
    """

    bound: np.ndarray
    halfspace_sum: np.ndarray
    n_constraints: np.ndarray
    tail: np.ndarray
    mean_in_collision: np.ndarray


def precision_cholesky_from_covariance(covariance) -> np.ndarray:
    """``U`` (upper triangular, ``Sigma^{-1} = U^T U``) from covariances.

    Raises :class:`InvalidInputError` for non-finite, non-symmetric or non-positive-definite input.

    Parameters
    ----------
    covariance : array_like, (..., d, d)
        Covariances ``Sigma``.

    Returns
    -------
    numpy.ndarray, (..., d, d)
        Upper triangular ``U`` with a positive diagonal.
    """
    cov = as_array(covariance, "covariance", finite=False)
    if cov.ndim < 2 or cov.shape[-1] != cov.shape[-2]:
        raise InvalidInputError(f"covariance: expected shape (..., d, d), got {cov.shape}")
    if not np.all(np.isfinite(cov)):
        raise InvalidInputError("covariance: contains NaN or inf")
    scale = np.abs(cov).max() if cov.size else 1.0
    if np.any(np.abs(cov - np.swapaxes(cov, -1, -2)) > 1e-10 * max(scale, 1e-300)):
        raise InvalidInputError("covariance: not symmetric")
    try:
        np.linalg.cholesky(cov)  # fails unless Sigma is positive definite
        # Sigma^{-1} = L_p L_p^T (lower Cholesky of the precision), so U = L_p^T is upper with U^T U = Sigma^{-1}.
        prec = np.linalg.inv(cov)
        prec = 0.5 * (prec + np.swapaxes(prec, -1, -2))
        lp = np.linalg.cholesky(prec)
    except np.linalg.LinAlgError as exc:
        raise InvalidInputError("covariance: not positive definite") from exc
    return np.swapaxes(lp, -1, -2).copy()


def check_gaussians(means, precision_cholesky, d: int) -> tuple[np.ndarray, np.ndarray]:
    """Validate ``means (..., d)`` and ``precision_cholesky (..., d, d)``; return float64 arrays."""
    mu = as_array(means, "means", finite=False)
    u = as_array(precision_cholesky, "precision_cholesky", finite=False)
    if mu.ndim < 1 or mu.shape[-1] != d:
        raise InvalidInputError(
            f"means: expected shape (..., {d}) to match the {d}-D environment, got {mu.shape}"
        )
    if u.shape != mu.shape + (d,):
        raise InvalidInputError(
            f"precision_cholesky: expected shape {mu.shape + (d,)}, got {u.shape}"
        )
    if not np.all(np.isfinite(mu)):
        raise InvalidInputError("means: contain NaN or inf")
    if not np.all(np.isfinite(u)):
        raise InvalidInputError(
            "precision_cholesky: contains NaN or inf (covariance not finite or singular)"
        )
    if np.any(np.tril(u, -1) != 0):
        raise InvalidInputError("precision_cholesky: must be upper triangular")
    diag = np.diagonal(u, axis1=-2, axis2=-1)
    if np.any(diag <= 0):
        raise InvalidInputError(
            f"precision_cholesky: diagonal must be positive (precision not positive definite); smallest {diag.min():.3g}"
        )
    return mu, u


def _patil(environment: Environment, mus, us, cutoff, record: bool):
    """:func:`~riskplan.collision._kernels.gaussian_bounds` (the Patil construction) of the
    Gaussians ``mus (N, d)``, ``us (N, d, d)`` against ``environment``; ``record`` keeps the
    half-spaces of the first one."""
    centers, radii = environment._spheres
    return K.gaussian_bounds(
        environment.vertices, environment.faces, centers, radii, mus, us, float(cutoff),
        BEHIND_EPS, record,
    )  # fmt: skip


def gaussian_bound_terms(
    means,
    precision_cholesky,
    environment: Environment,
    *,
    cutoff: float = DEFAULT_CUTOFF,
    validate: bool = True,
) -> GaussianBoundTerms:
    """The Patil-2012 bound for a batch of Gaussians, with its pieces. See :func:`gaussian_bound`.

    Parameters
    ----------
    means : array_like, (..., d)
        Gaussian means.
    precision_cholesky : array_like, (..., d, d)
        Upper triangular ``U`` with ``Sigma^{-1} = U^T U``.
    environment : Environment
        Obstacles of the same dimension ``d``.
    cutoff : float
        Whitened radius beyond which faces are not visited.
    validate : bool
        Check shapes and values.

    Returns
    -------
    GaussianBoundTerms
        ``bound``, ``halfspace_sum``, ``n_constraints``, ``tail`` and ``mean_in_collision``,
        each ``(...,)``.
    """
    if not isinstance(environment, Environment):
        raise InvalidInputError(
            f"environment: expected an Environment, got {type(environment).__name__}"
        )
    d = environment.dim
    if validate:
        mu, u = check_gaussians(means, precision_cholesky, d)
    else:
        mu, u = (
            np.asarray(means, dtype=np.float64),
            np.asarray(precision_cholesky, dtype=np.float64),
        )
    if not (cutoff > 0):
        raise InvalidInputError(f"cutoff: expected > 0, got {cutoff}")
    shape = mu.shape[:-1]
    mus = np.ascontiguousarray(mu.reshape(-1, d))
    us = np.ascontiguousarray(u.reshape(-1, d, d))
    s, ncons, touching, truncated, _, _, _ = _patil(environment, mus, us, cutoff, False)
    if not np.all(
        np.isfinite(s)
    ):  # the kernel is built to avoid this; never return NaN as a probability
        bad = int(np.flatnonzero(~np.isfinite(s))[0])
        raise InvalidInputError(
            f"means/precision_cholesky: the bound is not finite for Gaussian {bad} (numerically degenerate input)"
        )
    inside = environment.contains(mus) | touching
    tail = np.where(truncated, chi_tail(cutoff, d), 0.0)
    bound = np.where(inside, 1.0, np.clip(s + tail, 0.0, 1.0))
    return GaussianBoundTerms(
        bound=bound.reshape(shape),
        halfspace_sum=s.reshape(shape),
        n_constraints=ncons.reshape(shape),
        tail=tail.reshape(shape),
        mean_in_collision=inside.reshape(shape),
    )


def gaussian_bound(
    means,
    precision_cholesky,
    environment: Environment,
    *,
    cutoff: float = DEFAULT_CUTOFF,
    validate: bool = True,
) -> np.ndarray:
    r"""Upper bound on ``P(x in obstacles)`` for ``x ~ N(mu, (U^T U)^{-1})`` (Patil et al. 2012).

    In the whitened frame ``y = U (x - mu)`` each face nearer than ``cutoff`` adds the
    half-space of its nearest point at whitened distance ``b_j``; the region they leave free is
    convex and contains the mean, so

    .. math:: P(x \in \mathcal{O}) \le \min\Bigl(1, \sum_j \bigl(1 - \Phi(b_j)\bigr)
       + P(\lVert y \rVert \ge \text{cutoff})\Bigr)

    Parameters
    ----------
    means : array_like, (..., d)
        Gaussian means.
    precision_cholesky : array_like, (..., d, d)
        Upper triangular ``U`` with ``Sigma^{-1} = U^T U`` (MDN paper eq. 3).
    environment : Environment
        Obstacles of the same dimension ``d`` (2 or 3).
    cutoff : float
        Whitened radius beyond which faces are not visited (see the module docstring).
    validate : bool
        Check shapes, finiteness and the triangle of ``U`` (skip for inputs checked already).

    Returns
    -------
    numpy.ndarray, (...,)
        float64 in [0, 1]; 1 where the mean is in collision.
    """
    return gaussian_bound_terms(
        means, precision_cholesky, environment, cutoff=cutoff, validate=validate
    ).bound


@dataclass(frozen=True)
class FreeRegion:
    """The convex free region of one Gaussian: ``{x : normals @ x <= offsets}`` in world
    coordinates, and ``{y : whitened_normals @ y <= distances}`` in whitened coordinates."""

    normals: np.ndarray  # (J, d)
    offsets: np.ndarray  # (J,)
    whitened_normals: np.ndarray  # (J, d), unit
    distances: np.ndarray  # (J,) = b_j

    @property
    def bound_terms(self) -> np.ndarray:
        """``1 - Phi(b_j)`` per constraint."""
        from scipy.special import ndtr

        return ndtr(-self.distances)


def free_region(
    mean, precision_cholesky, environment: Environment, *, cutoff: float = DEFAULT_CUTOFF
) -> FreeRegion:
    r"""Half-spaces of the Patil construction for one Gaussian.

    World form of a whitened half-space ``a . y <= b``:

    .. math:: a^\top \bar U (x - \mu) \le b \iff (\bar U^\top a)^\top x \le b + (\bar U^\top a)^\top \mu

    Parameters
    ----------
    mean : array_like, (d,)
        The Gaussian's mean ``mu``.
    precision_cholesky : array_like, (d, d)
        Upper triangular ``U``.
    environment : Environment
        Obstacles of dimension ``d``.
    cutoff : float
        Whitened radius beyond which faces are not visited.

    Returns
    -------
    FreeRegion
        ``J`` half-spaces in world and whitened form, with their distances ``b_j``.
    """
    mu, u = check_gaussians(
        np.asarray(mean)[None], np.asarray(precision_cholesky)[None], environment.dim
    )
    _, _, _, _, A, B, _ = _patil(environment, mu, u, cutoff, True)
    normals = A @ u[0]
    return FreeRegion(normals=normals, offsets=B + normals @ mu[0], whitened_normals=A, distances=B)


def gaussian_bound_covariance(
    means, covariances, environment: Environment, *, cutoff: float = DEFAULT_CUTOFF
) -> np.ndarray:
    """:func:`gaussian_bound` for Gaussians given by covariances.

    For example the LQG-MP state distributions of the deformable-planning paper (section IV-D).

    Parameters
    ----------
    means : array_like, (..., d)
        Gaussian means.
    covariances : array_like, (..., d, d)
        Symmetric positive-definite covariances; :class:`InvalidInputError` otherwise.
    environment : Environment
        Obstacles of dimension ``d``.
    cutoff : float
        Whitened radius beyond which faces are not visited.

    Returns
    -------
    numpy.ndarray, (...,)
        Bounds in [0, 1].
    """
    return gaussian_bound(
        means, precision_cholesky_from_covariance(covariances), environment, cutoff=cutoff
    )
