r"""Batched Gaussian mixtures as NumPy arrays: the mixture core (MDN paper, eqs. 1-6), no torch.

Every package that reads mixtures builds on this module: the collision estimators and the
planners use :class:`NumpyMixture` directly; the learned kinematics' differentiable torch type
:class:`riskplan.kinematics.GaussianMixture` converts to it (``.to_numpy()``) and validates its
parameters and converts covariances through the functions here.

Parameterisation (eqs. 1-6): component ``k`` has weight ``w_k``, mean ``mu_k`` and an
upper-triangular matrix ``U_k`` with positive diagonal such that the precision is
``Sigma_k^{-1} = U_k^T U_k`` (eq. 3). Then

    log N(x; mu_k, Sigma_k) = -d/2 log(2 pi) + sum_i log U_k[i, i] - 1/2 ||U_k (x - mu_k)||^2

(eqs. 4-6: ``det Sigma^{-1/2} = prod diag U`` and the quadratic form is a squared norm), and
``log p(x) = logsumexp_k (log w_k + log N(x; mu_k, Sigma_k))`` (eq. 1). In the paper's
notation:

.. math::

    p(x) = \sum_{k=1}^{K} w_k \, \mathcal{N}(x; \mu_k, \Sigma_k), \quad w_k \ge 0,
    \ \sum_k w_k = 1 \qquad \text{(eq. 1)}

    \Sigma_k^{-1} = U_k^\top U_k \qquad \text{(eq. 3)}

    \log |\Sigma_k^{-1}|^{1/2} = \sum_{j=1}^{d} \log (U_k)_{jj} \qquad
    \text{(eqs. 4-6)}

    \log \mathcal{N}(x; \mu_k, \Sigma_k) = -\frac{d}{2} \log 2\pi
    + \sum_{j} \log (U_k)_{jj} - \frac{1}{2} \| U_k (x - \mu_k) \|^2.

No matrix is inverted or factorised to evaluate a density. A draw is ``x = mu_k + U_k^{-1} z`` with ``k ~ w`` and
``z ~ N(0, I)``: its covariance is ``U_k^{-1} U_k^{-T} = Sigma_k``.

Shapes (leading batch axes ``...`` are shared by all three arrays)::

    weights            (..., K)
    means              (..., K, d)
    precision_cholesky (..., K, d, d)   upper triangular, positive diagonal

>>> gm = NumpyMixture.from_covariances([0.5, 0.5], [[0.0, 0.0], [2.0, 0.0]], [np.eye(2)] * 2)
>>> gm.batch_shape, gm.n_components, gm.dim
((), 2, 2)
>>> gm.mean()
array([1., 0.])
>>> gm.log_prob([[0.0, 0.0]]).shape
(1,)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_generator, check_count
from riskplan.errors import InvalidInputError

__all__ = [
    "FIELDS",
    "WEIGHT_SUM_ATOL",
    "MixtureBatch",
    "NumpyMixture",
    "as_numpy_mixture",
    "check_mixture_arrays",
    "check_point_shape",
    "draw_components",
    "precision_cholesky_from_covariances",
]

#: how far the weights of a mixture may sum from 1
WEIGHT_SUM_ATOL = 1e-5
#: the parameters' names, in the constructors' order
FIELDS = ("weights", "means", "precision_cholesky")


def check_mixture_arrays(weights, means, precision_cholesky) -> None:
    """Raise :class:`InvalidInputError` unless the arrays form a valid batch of mixtures.

    Shapes ``(..., K)``, ``(..., K, d)``, ``(..., K, d, d)`` with ``K, d >= 1``; finite values;
    non-negative weights summing to 1 (within :data:`WEIGHT_SUM_ATOL`) over the last axis;
    ``U`` upper triangular with a positive diagonal. Works on any real dtype.
    """
    w, m, u = weights, means, precision_cholesky
    if w.ndim < 1 or m.ndim < 2 or u.ndim < 3:
        raise InvalidInputError(
            "GaussianMixture: expected weights (..., K), means (..., K, d), precision_cholesky "
            f"(..., K, d, d); got {tuple(w.shape)}, {tuple(m.shape)}, {tuple(u.shape)}"
        )
    K, d = m.shape[-2], m.shape[-1]
    if tuple(w.shape) != tuple(m.shape[:-1]):
        raise InvalidInputError(
            f"weights: shape {tuple(w.shape)} does not match means {tuple(m.shape)} "
            f"(expected {tuple(m.shape[:-1])})"
        )
    if tuple(u.shape) != tuple(m.shape) + (d,):
        raise InvalidInputError(
            f"precision_cholesky: expected shape {tuple(m.shape) + (d,)}, got {tuple(u.shape)}"
        )
    if K < 1 or d < 1:
        raise InvalidInputError(f"GaussianMixture: need K >= 1 and d >= 1, got K={K}, d={d}")
    for name, a in zip(FIELDS, (w, m, u)):
        if not np.isfinite(a).all():
            raise InvalidInputError(f"{name}: contains NaN or inf")
    if (w < 0).any():
        raise InvalidInputError("weights: must be non-negative")
    total = w.sum(-1)
    if not np.allclose(total, 1.0, atol=WEIGHT_SUM_ATOL, rtol=0):
        worst = float(np.abs(total - 1).max())
        raise InvalidInputError(
            f"weights: must sum to 1 over the last axis (worst deviation {worst:.3g})"
        )
    if (np.tril(u, -1) != 0).any():
        raise InvalidInputError(
            "precision_cholesky: must be upper triangular (entries below the diagonal are non-zero)"
        )
    diag = np.diagonal(u, axis1=-2, axis2=-1)
    if (diag <= 0).any():
        raise InvalidInputError(
            "precision_cholesky: diagonal must be positive (the precision must be positive "
            f"definite); smallest diagonal entry {float(diag.min()):.3g}"
        )


def check_point_shape(shape: tuple, dim: int, batch_shape: tuple) -> None:
    """Raise :class:`InvalidInputError` unless points of ``shape`` are ``(..., N, dim)`` with
    leading axes that broadcast against ``batch_shape``."""
    if len(shape) < 2 or shape[-1] != dim:
        raise InvalidInputError(
            f"points: expected shape (..., N, {dim}) for a {dim}-D mixture, got {tuple(shape)}"
        )
    try:
        np.broadcast_shapes(tuple(shape[:-2]), tuple(batch_shape))
    except ValueError as exc:
        raise InvalidInputError(
            f"points: leading shape {tuple(shape[:-2])} does not broadcast against the batch "
            f"shape {tuple(batch_shape)}"
        ) from exc


def precision_cholesky_from_covariances(covariances) -> np.ndarray:
    """``U = chol(Sigma^{-1})^T`` (upper triangular, ``U^T U = Sigma^{-1}``) for ``(..., d, d)``.

    The precision is symmetrised before its Cholesky factorisation, so round-off asymmetry in
    ``Sigma`` is accepted. Raises :class:`InvalidInputError` for NaN/inf or a covariance that is
    not symmetric positive definite. (The collision package's stricter
    ``precision_cholesky_from_covariance`` also rejects visibly asymmetric input.)
    """
    cov = _as_real_array(covariances, "covariances")
    if cov.ndim < 2 or cov.shape[-1] != cov.shape[-2]:
        raise InvalidInputError(f"covariances: expected shape (..., d, d), got {cov.shape}")
    if not np.isfinite(cov).all():
        raise InvalidInputError("covariances: contains NaN or inf")
    try:
        prec = np.linalg.inv(cov)
        lower = np.linalg.cholesky(0.5 * (prec + np.swapaxes(prec, -1, -2)))
    except np.linalg.LinAlgError as exc:
        raise InvalidInputError(f"covariances: not symmetric positive definite ({exc})") from exc
    return np.ascontiguousarray(np.swapaxes(lower, -1, -2))


def draw_components(
    rng: np.random.Generator,
    weights: np.ndarray,
    means: np.ndarray,
    covariance_factors: np.ndarray,
    n: int,
    *,
    one_per_component: bool = False,
) -> np.ndarray:
    """Draws ``(B, n, S, d)`` from ``B`` mixtures ``weights (B, K)``, ``means (B, K, d)``,
    ``covariance_factors (B, K, d, d)`` (``U^{-1}``, see :attr:`NumpyMixture.covariance_factors`).

    ``S = 1``: a point from the mixture (component by inverse CDF of the weights).
    ``one_per_component``: ``S = K``, one point from every component (the union quantity of
    the collision bounds). One ``rng.random`` call for the components, then one
    ``rng.standard_normal`` call.
    """
    B, K, d = means.shape
    if not one_per_component:
        cdf = np.cumsum(weights, axis=-1)
        cdf[:, -1] = np.inf  # guards round-off: every uniform falls in some component
        u = rng.random((B, n))
        comp = (u[..., None] >= cdf[:, None, :]).sum(-1)  # (B, n)
        comp = np.minimum(comp, K - 1)[..., None]  # (B, n, 1)
    else:
        comp = np.broadcast_to(np.arange(K), (B, n, K))
    z = rng.standard_normal(comp.shape + (d,))
    bi = np.arange(B)[:, None, None]
    mu = means[bi, comp]  # (B, n, S, d)
    L = covariance_factors[bi, comp]  # (B, n, S, d, d)
    return mu + np.einsum("...ij,...j->...i", L, z)


class MixtureBatch:
    """Shape properties and batch indexing shared by :class:`NumpyMixture` and the torch
    ``GaussianMixture``: both hold ``weights``, ``means``, ``precision_cholesky`` and take
    ``(weights, means, precision_cholesky, *, validate)`` in their constructors."""

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.weights.shape[:-1]

    @property
    def n_components(self) -> int:
        return self.weights.shape[-1]

    @property
    def dim(self) -> int:
        return self.means.shape[-1]

    def __getitem__(self, idx):
        """Index the batch axes: ``gm[3]``, ``gm[:, 0]`` (a mixture of the same type)."""
        if not isinstance(idx, tuple):
            idx = (idx,)
        if Ellipsis in idx:
            raise InvalidInputError(
                f"{type(self).__name__} indexing: Ellipsis is not supported; index batch axes "
                "explicitly"
            )
        if len(idx) > len(self.batch_shape):
            raise InvalidInputError(f"too many indices for batch shape {tuple(self.batch_shape)}")
        return type(self)(*(getattr(self, name)[idx] for name in FIELDS), validate=False)


@dataclass(frozen=True, eq=False)
class NumpyMixture(MixtureBatch):
    """A batch of ``K``-component Gaussian mixtures in ``d`` dimensions, as float64 arrays.

    Construct from arrays (anything ``numpy.asarray`` reads as real numbers); they become
    float64 (no copy when they already are). Pass ``validate=False`` only from code that built
    the parameters itself. The arrays are not copied or frozen: do not change them afterwards.
    """

    weights: np.ndarray
    means: np.ndarray
    precision_cholesky: np.ndarray

    def __init__(self, weights, means, precision_cholesky, *, validate: bool = True):
        for name, x in zip(FIELDS, (weights, means, precision_cholesky)):
            object.__setattr__(self, name, _as_real_array(x, name))
        if validate:
            self.validate()

    def validate(self) -> None:
        """Raise :class:`InvalidInputError` if the parameters do not form a valid mixture."""
        check_mixture_arrays(self.weights, self.means, self.precision_cholesky)

    @classmethod
    def from_covariances(cls, weights, means, covariances, *, validate: bool = True):
        """Build from covariances ``(..., K, d, d)`` (:func:`precision_cholesky_from_covariances`)."""
        return cls(
            weights, means, precision_cholesky_from_covariances(covariances), validate=validate
        )

    # ------------------------------------------------------------ properties
    @property
    def covariance_factors(self) -> np.ndarray:
        """``U_k^{-1}`` (upper triangular, ``U^{-1} U^{-T} = Sigma``), shape ``(..., K, d, d)``."""
        return np.linalg.inv(self.precision_cholesky)

    @property
    def covariances(self) -> np.ndarray:
        """``Sigma_k = U_k^{-1} U_k^{-T}``, shape ``(..., K, d, d)``."""
        a = self.covariance_factors
        with np.errstate(over="ignore", invalid="ignore"):
            cov = a @ np.swapaxes(a, -1, -2)
        _check_covariance(cov)
        return cov

    @property
    def precisions(self) -> np.ndarray:
        """``Sigma_k^{-1} = U_k^T U_k``, shape ``(..., K, d, d)``."""
        u = self.precision_cholesky
        return np.swapaxes(u, -1, -2) @ u

    # ---------------------------------------------------------------- moments
    def mean(self) -> np.ndarray:
        """Mean of each mixture, ``sum_k w_k mu_k``; shape ``(..., d)``."""
        return np.einsum("...k,...ki->...i", self.weights, self.means)

    def covariance(self) -> np.ndarray:
        """Covariance of each mixture (law of total covariance); shape ``(..., d, d)``:
        ``sum_k w_k (Sigma_k + (mu_k - mu)(mu_k - mu)^T)`` with ``mu`` the mixture mean."""
        dev = self.means - self.mean()[..., None, :]
        spread = self.covariances + dev[..., :, None] * dev[..., None, :]
        with np.errstate(over="ignore", invalid="ignore"):
            cov = np.einsum("...k,...kij->...ij", self.weights, spread)
        _check_covariance(cov)
        return cov

    # -------------------------------------------------------------- densities
    def _check_points(self, points) -> np.ndarray:
        """Validate points ``(..., N, d)``: leading axes broadcasting against the batch shape,
        finite real values; return them as float64."""
        if points is None or isinstance(points, (str, bytes)):
            raise InvalidInputError(
                f"points: expected a numeric array of shape (..., N, {self.dim}), got "
                f"{type(points).__name__}"
            )
        x = _as_real_array(points, "points")
        check_point_shape(x.shape, self.dim, self.batch_shape)
        if not np.isfinite(x).all():
            raise InvalidInputError("points: contain NaN or inf")
        return x

    def component_log_prob(self, points) -> np.ndarray:
        """``log N(x_n; mu_k, Sigma_k)`` (eqs. 4-6) for points ``(..., N, d)``; ``(..., K, N)``.

        Raises :class:`InvalidInputError` for points of the wrong dimension or type, a leading
        shape that does not broadcast against the batch shape, or NaN/inf values.
        """
        x = self._check_points(points)
        diff = x[..., None, :, :] - self.means[..., :, None, :]  # (..., K, N, d)
        with np.errstate(over="ignore", invalid="ignore"):
            y = np.einsum("...kij,...knj->...kni", self.precision_cholesky, diff)
            sq = (y * y).sum(-1)
        # inputs are finite, so a NaN here means U (x - mu) overflowed (inf - inf): the point is
        # astronomically far in Mahalanobis distance and its log density is -inf, not NaN
        sq = np.nan_to_num(sq, nan=np.inf)
        logdet = np.log(np.diagonal(self.precision_cholesky, axis1=-2, axis2=-1)).sum(-1)
        return -0.5 * sq + logdet[..., None] - 0.5 * self.dim * math.log(2.0 * math.pi)

    def log_prob(self, points) -> np.ndarray:
        """Mixture log density (eq. 1) of points ``(..., N, d)``; returns ``(..., N)``.

        The sum over components is a log-sum-exp (stable for far-away points); zero-weight
        components contribute ``-inf`` inside it and are ignored.
        """
        comp = self.component_log_prob(points)
        with np.errstate(divide="ignore"):
            a = np.log(self.weights)[..., None] + comp  # (..., K, N)
            top = a.max(-2)
            top = np.where(np.isfinite(top), top, 0.0)
            return np.log(np.exp(a - top[..., None, :]).sum(-2)) + top

    def sample(self, n: int, seed=None) -> np.ndarray:
        """Draw ``n`` points from each mixture; returns ``(..., n, d)``.

        ``seed``: ``None``, an int, a ``SeedSequence`` or a ``numpy.random.Generator``.
        """
        check_count(n, "n", 0)
        K, d = self.n_components, self.dim
        from riskplan.budget import check_budget

        batch = int(np.prod(self.batch_shape, dtype=np.float64))
        # the (..., n, d) result and the standard normal draws it is made from
        check_budget(
            f"{n} samples of {batch} mixture(s) in {d}-D",
            "n",
            nbytes=2.0 * 8 * batch * float(n) * d,
        )
        x = draw_components(
            as_generator(seed),
            self.weights.reshape(-1, K),
            self.means.reshape(-1, K, d),
            self.covariance_factors.reshape(-1, K, d, d),
            int(n),
        )
        return x.reshape(*self.batch_shape, int(n), d)

    # ------------------------------------------------------------- conversion
    def numpy(self) -> dict[str, np.ndarray]:
        """``{"weights", "means", "precision_cholesky"}`` (as the torch type's ``numpy()``)."""
        return {name: getattr(self, name) for name in FIELDS}

    def __repr__(self) -> str:
        return (
            f"NumpyMixture(batch_shape={tuple(self.batch_shape)}, K={self.n_components}, "
            f"d={self.dim})"
        )


def _check_covariance(cov: np.ndarray) -> None:
    """Raise :class:`NumericalError` when a covariance overflows float64 (a precision factor
    near 1e-160 or below); the precision-only computations (densities, bounds) still work."""
    if not np.all(np.isfinite(cov)):
        from riskplan.errors import NumericalError

        raise NumericalError(
            "covariance: overflows float64 (precision_cholesky is too close to singular); "
            "use the precision-only path (log_prob, collision bounds, sample), which never "
            "forms the covariance"
        )


def as_numpy_mixture(mixture, *, validate: bool = True) -> NumpyMixture:
    """A :class:`NumpyMixture` from a ``NumpyMixture``, a torch
    :class:`riskplan.kinematics.GaussianMixture` (its ``to_numpy()``) or any object with
    ``weights``, ``means`` and ``precision_cholesky`` arrays; re-validated when ``validate``.

    This is the boundary of the array code: it never imports torch.
    """
    if isinstance(mixture, NumpyMixture):
        if validate:
            mixture.validate()
        return mixture
    to_numpy = getattr(mixture, "to_numpy", None)
    if callable(to_numpy):
        out = to_numpy(validate=validate)
        if isinstance(out, NumpyMixture):
            return out
    if not all(hasattr(mixture, name) for name in FIELDS):
        raise InvalidInputError(
            f"mixture: expected a NumpyMixture or a GaussianMixture, got {type(mixture).__name__}"
        )
    return NumpyMixture(*(getattr(mixture, name) for name in FIELDS), validate=validate)


def _as_real_array(x, name: str) -> np.ndarray:
    """``x`` as a float64 array; :class:`InvalidInputError` for anything but real numbers."""
    try:
        arr = np.asarray(x)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise InvalidInputError(f"{name}: cannot convert to a numeric array ({exc})") from exc
    if arr.dtype.kind not in "fiu":
        raise InvalidInputError(
            f"{name}: expected a numeric array of real numbers, got dtype {arr.dtype}"
        )
    return arr.astype(np.float64, copy=False)
