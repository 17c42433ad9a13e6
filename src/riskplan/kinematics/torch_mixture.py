"""The differentiable torch Gaussian mixture the MDN predicts (MDN paper, eqs. 1-6).

:class:`GaussianMixture` holds the same parameters as the NumPy core
:class:`riskplan.gaussian_mixture.NumpyMixture` (whose docstring states the formulas) as torch
tensors, so densities keep their gradients and live on the network's device and dtype. It is
built on the core: parameters and points are checked by the core's functions, covariances are
converted there, and ``to_numpy()`` hands the mixture to the array code (collision, planning).

Shapes (leading batch axes ``...`` are shared by all three tensors)::

    weights            (..., K)
    means              (..., K, d)
    precision_cholesky (..., K, d, d)   upper triangular, positive diagonal
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from riskplan._validation import check_count
from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import (
    FIELDS,
    MixtureBatch,
    NumpyMixture,
    check_mixture_arrays,
    check_point_shape,
    precision_cholesky_from_covariances,
)


@dataclass(frozen=True, eq=False)
class GaussianMixture(MixtureBatch):
    """A batch of ``K``-component Gaussian mixtures in ``d`` dimensions.

    Construct with tensors or arrays; NumPy inputs become float64 tensors. Pass
    ``validate=False`` only from code that built the parameters itself (e.g. the
    network's heads), where the checks would cost time in a hot loop.
    """

    weights: torch.Tensor
    means: torch.Tensor
    precision_cholesky: torch.Tensor

    def __init__(self, weights, means, precision_cholesky, *, validate: bool = True):
        w, m, u = (_as_tensor(x) for x in (weights, means, precision_cholesky))
        dtype = torch.promote_types(torch.promote_types(w.dtype, m.dtype), u.dtype)
        w, m, u = w.to(dtype), m.to(dtype), u.to(dtype)
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "means", m)
        object.__setattr__(self, "precision_cholesky", u)
        if validate:
            self.validate()

    # ------------------------------------------------------------------ checks
    def validate(self) -> None:
        """Raise :class:`InvalidInputError` if the parameters do not form a valid mixture
        (:func:`riskplan.gaussian_mixture.check_mixture_arrays` on detached CPU copies)."""
        check_mixture_arrays(*(_host_array(getattr(self, name)) for name in FIELDS))

    # ------------------------------------------------------------ properties
    # batch_shape (a torch.Size here), n_components, dim and batch indexing: MixtureBatch
    @property
    def dtype(self) -> torch.dtype:
        return self.means.dtype

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def covariances(self) -> torch.Tensor:
        """``Sigma_k = U_k^{-1} U_k^{-T}``, shape ``(..., K, d, d)``."""
        uinv = self._inverse_cholesky()
        return uinv @ uinv.transpose(-1, -2)

    @property
    def precisions(self) -> torch.Tensor:
        """``Sigma_k^{-1} = U_k^T U_k``, shape ``(..., K, d, d)``."""
        u = self.precision_cholesky
        return u.transpose(-1, -2) @ u

    def _inverse_cholesky(self) -> torch.Tensor:
        u = self.precision_cholesky
        eye = torch.eye(self.dim, dtype=u.dtype, device=u.device).expand_as(u)
        return torch.linalg.solve_triangular(u, eye, upper=True)

    # ----------------------------------------------------------- densities
    def _check_points(self, points) -> torch.Tensor:
        """Validate points ``(..., N, d)`` against this mixture; return them in its dtype.

        The leading axes ``...`` must broadcast against the batch shape; values must be finite.
        """
        if points is None or isinstance(points, (str, bytes)):
            raise InvalidInputError(
                f"points: expected a numeric array of shape (..., N, {self.dim}), got {type(points).__name__}"
            )
        try:
            x = _as_tensor(points)
        except InvalidInputError as exc:
            raise InvalidInputError(f"points: {exc}") from exc
        except (TypeError, ValueError, RuntimeError) as exc:
            raise InvalidInputError(f"points: cannot convert to a numeric array ({exc})") from exc
        if x.is_complex() or x.dtype == torch.bool:
            raise InvalidInputError(f"points: expected real numbers, got dtype {x.dtype}")
        check_point_shape(tuple(x.shape), self.dim, tuple(self.batch_shape))
        if not torch.isfinite(x).all():
            raise InvalidInputError("points: contain NaN or inf")
        return x.to(self.dtype)

    def component_log_prob(self, points) -> torch.Tensor:
        r"""Component log densities (eqs. 4-6 of the MDN paper),

        .. math::

            \log \mathcal{N}(x_n; \mu_k, \Sigma_k) = -\frac{d}{2} \log 2\pi + \sum_j \log (U_k)_{jj}
            - \frac{1}{2} \| U_k (x_n - \mu_k) \|^2.

        Parameters
        ----------
        points : array_like or torch.Tensor
            ``(..., N, d)``; the leading shape broadcasts against the batch shape.

        Returns
        -------
        torch.Tensor
            ``(..., K, N)``.

        Raises
        ------
        InvalidInputError
            Points of the wrong dimension or type, a leading shape that does not broadcast, or
            NaN/inf values.
        """
        x = self._check_points(points)
        diff = x.unsqueeze(-3) - self.means.unsqueeze(-2)  # (..., K, N, d)
        # U (x - mu): row i is sum_j U[i, j] diff[j]
        y = torch.einsum("...kij,...knj->...kni", self.precision_cholesky, diff)
        sq = (y * y).sum(-1)
        # inputs are finite, so a NaN here means U (x - mu) overflowed (inf - inf): the point is
        # astronomically far in Mahalanobis distance and its log density is -inf, not NaN
        sq = torch.nan_to_num(sq, nan=math.inf)
        logdet = torch.log(torch.diagonal(self.precision_cholesky, dim1=-2, dim2=-1)).sum(-1)
        return -0.5 * sq + logdet.unsqueeze(-1) - 0.5 * self.dim * math.log(2.0 * math.pi)

    def log_prob(self, points) -> torch.Tensor:
        r"""Mixture log density (eq. 1), :math:`\log \sum_k w_k \mathcal{N}(x; \mu_k, \Sigma_k)`.

        Stable for far-away points: the sum over components is a log-sum-exp; zero-weight
        components contribute ``-inf`` inside it and are ignored.

        Parameters
        ----------
        points : array_like or torch.Tensor
            ``(..., N, d)``.

        Returns
        -------
        torch.Tensor
            ``(..., N)``.
        """
        comp = self.component_log_prob(points)
        logw = torch.log(self.weights).unsqueeze(-1)
        return torch.logsumexp(logw + comp, dim=-2)

    def sample(self, n: int, seed=None) -> torch.Tensor:
        """Draw points from each mixture: ``x = mu_k + U_k^{-1} z`` with ``k ~ w``, ``z ~ N(0, I)``.

        The draws come from torch's generator, so they differ from ``to_numpy().sample(n, seed)``
        (same distribution).

        Parameters
        ----------
        n : int
            Points per mixture (>= 0).
        seed : None, int or torch.Generator
            The random stream.

        Returns
        -------
        torch.Tensor
            ``(..., n, d)``.
        """
        if n < 0:
            raise InvalidInputError(f"n: expected >= 0, got {n}")
        if isinstance(seed, torch.Generator):
            gen = seed
        else:
            seed = check_count(seed, "seed", 0, none=True, alternatives="a torch.Generator")
            gen = torch.Generator().manual_seed(
                int(np.random.SeedSequence(seed).generate_state(1)[0])
            )
        batch = self.batch_shape
        K, d = self.n_components, self.dim
        w = self.weights.reshape(-1, K).detach().cpu().double()
        comp = (
            torch.multinomial(w, n, replacement=True, generator=gen)
            if n
            else torch.zeros(w.shape[0], 0, dtype=torch.long)
        )
        z = torch.randn(w.shape[0], n, d, generator=gen, dtype=torch.float64).to(self.dtype)
        comp = comp.to(self.device)
        z = z.to(self.device)
        means = self.means.reshape(-1, K, d)
        u = self.precision_cholesky.reshape(-1, K, d, d)
        idx = comp.unsqueeze(-1)
        mu = torch.gather(means, 1, idx.expand(-1, -1, d))  # (B, n, d)
        uu = torch.gather(u, 1, idx.unsqueeze(-1).expand(-1, -1, d, d))  # (B, n, d, d)
        # x = mu + U^{-1} z  has covariance U^{-1} U^{-T} = Sigma.
        x = mu + torch.linalg.solve_triangular(uu, z.unsqueeze(-1), upper=True).squeeze(-1)
        return x.reshape(*batch, n, d)

    # ------------------------------------------------------------ conversion
    def to(self, *args, **kwargs) -> GaussianMixture:
        """Like ``torch.Tensor.to`` (dtype and/or device) for all parameters.

        Parameters
        ----------
        *args, **kwargs
            Passed to ``torch.Tensor.to`` for each tensor.

        Returns
        -------
        GaussianMixture
            Not validated again.
        """
        return GaussianMixture(
            self.weights.to(*args, **kwargs),
            self.means.to(*args, **kwargs),
            self.precision_cholesky.to(*args, **kwargs),
            validate=False,
        )

    def detach(self) -> GaussianMixture:
        """The mixture with its tensors detached from the autograd graph.

        Returns
        -------
        GaussianMixture
        """
        return GaussianMixture(
            self.weights.detach(),
            self.means.detach(),
            self.precision_cholesky.detach(),
            validate=False,
        )

    def numpy(self) -> dict[str, np.ndarray]:
        """The parameters as NumPy arrays (detached, on CPU, in the tensors' dtype).

        Returns
        -------
        dict of str to numpy.ndarray
            ``weights (..., K)``, ``means (..., K, d)``, ``precision_cholesky (..., K, d, d)``.
        """
        return {name: getattr(self, name).detach().cpu().numpy() for name in FIELDS}

    def to_numpy(self, *, validate: bool = True) -> NumpyMixture:
        """This mixture as a float64 :class:`~riskplan.gaussian_mixture.NumpyMixture`.

        Parameters
        ----------
        validate : bool
            Check the arrays again (weights sum to one, ``U`` upper triangular, finite).

        Returns
        -------
        NumpyMixture
            Detached, on CPU; no copy for float64 CPU tensors.
        """
        return NumpyMixture(
            *(_host_array(getattr(self, name)) for name in FIELDS), validate=validate
        )

    @classmethod
    def from_numpy(
        cls, weights, means, precision_cholesky, *, validate: bool = True
    ) -> GaussianMixture:
        """Build from NumPy arrays (or anything ``numpy.asarray`` takes).

        Parameters
        ----------
        weights : array_like, (..., K)
            Component weights, summing to one.
        means : array_like, (..., K, d)
            Component means.
        precision_cholesky : array_like, (..., K, d, d)
            Upper triangular ``U`` with ``Sigma^{-1} = U^T U``.
        validate : bool
            Check shapes and values.

        Returns
        -------
        GaussianMixture
        """
        return cls(
            np.asarray(weights),
            np.asarray(means),
            np.asarray(precision_cholesky),
            validate=validate,
        )

    @classmethod
    def from_numpy_mixture(
        cls, mixture: NumpyMixture, *, validate: bool = False
    ) -> GaussianMixture:
        """The torch mixture of a :class:`~riskplan.gaussian_mixture.NumpyMixture`.

        Parameters
        ----------
        mixture : NumpyMixture
            The mixture; its float64 arrays become tensors sharing their memory.
        validate : bool
            Check again (the NumPy mixture was checked when built).

        Returns
        -------
        GaussianMixture
        """
        return cls(*(getattr(mixture, name) for name in FIELDS), validate=validate)

    @classmethod
    def from_covariances(
        cls, weights, means, covariances, *, validate: bool = True
    ) -> GaussianMixture:
        """Build from covariances: ``U = chol(Sigma^{-1})^T``.

        The factor is computed in float64 by
        :func:`riskplan.gaussian_mixture.precision_cholesky_from_covariances` (not
        differentiable) and returned in the covariances' dtype and device.

        Parameters
        ----------
        weights : torch.Tensor or array_like, (..., K)
            Component weights, summing to one.
        means : torch.Tensor or array_like, (..., K, d)
            Component means.
        covariances : torch.Tensor or array_like, (..., K, d, d)
            Symmetric positive-definite covariances.
        validate : bool
            Check shapes and values.

        Returns
        -------
        GaussianMixture
        """
        cov = covariances
        if isinstance(cov, torch.Tensor):
            u = precision_cholesky_from_covariances(_host_array(cov))
            u = torch.as_tensor(u).to(dtype=cov.dtype, device=cov.device)
        else:
            u = precision_cholesky_from_covariances(cov)
        return cls(weights, means, u, validate=validate)

    def __repr__(self) -> str:
        return (
            f"GaussianMixture(batch_shape={tuple(self.batch_shape)}, K={self.n_components}, d={self.dim}, "
            f"dtype={self.dtype})"
        )


def _host_array(t: torch.Tensor) -> np.ndarray:
    """``t`` as a NumPy array on the host (detached; float64 unless float32 or float64)."""
    t = t.detach().cpu()
    if t.dtype not in (torch.float32, torch.float64):
        t = t.to(torch.float64)
    return t.numpy()


def _as_tensor(x) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x
    arr = np.asarray(x)
    if arr.dtype.kind not in "fiu":
        raise InvalidInputError(f"expected a numeric array, got dtype {arr.dtype}")
    return torch.as_tensor(arr, dtype=torch.float64 if arr.dtype.kind in "iu" else None)
