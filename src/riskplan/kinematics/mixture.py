"""Batched Gaussian mixtures parameterised by precision Cholesky factors.

This type is the seam between the learned kinematics (which produce it), the
collision estimators (which consume it) and the planners.

Parameterisation (MDN paper, eqs. 1-6): component ``k`` has weight ``w_k``, mean
``mu_k`` and an upper-triangular matrix ``U_k`` with positive diagonal such that the
precision is ``Sigma_k^{-1} = U_k^T U_k`` (eq. 3). Then

    log N(x; mu_k, Sigma_k) = -d/2 log(2 pi) + sum_i log U_k[i, i] - 1/2 ||U_k (x - mu_k)||^2

(eqs. 4-6: ``det Sigma^{-1/2} = prod diag U`` and the quadratic form is a squared norm),
and ``log p(x) = logsumexp_k (log w_k + log N(x; mu_k, Sigma_k))`` (eq. 1).

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

from riskplan.errors import InvalidInputError

WEIGHT_SUM_ATOL = 1e-5


@dataclass(frozen=True, eq=False)
class GaussianMixture:
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
        """Raise :class:`InvalidInputError` if the parameters do not form a valid mixture."""
        w, m, u = self.weights, self.means, self.precision_cholesky
        if w.ndim < 1 or m.ndim < 2 or u.ndim < 3:
            raise InvalidInputError(
                f"GaussianMixture: expected weights (..., K), means (..., K, d), precision_cholesky (..., K, d, d); "
                f"got {tuple(w.shape)}, {tuple(m.shape)}, {tuple(u.shape)}"
            )
        K, d = m.shape[-2], m.shape[-1]
        if w.shape != m.shape[:-1]:
            raise InvalidInputError(
                f"weights: shape {tuple(w.shape)} does not match means {tuple(m.shape)} (expected {tuple(m.shape[:-1])})"
            )
        if u.shape != m.shape + (d,):
            raise InvalidInputError(
                f"precision_cholesky: expected shape {tuple(m.shape) + (d,)}, got {tuple(u.shape)}"
            )
        if K < 1 or d < 1:
            raise InvalidInputError(f"GaussianMixture: need K >= 1 and d >= 1, got K={K}, d={d}")
        for name, t in (("weights", w), ("means", m), ("precision_cholesky", u)):
            if not torch.isfinite(t).all():
                raise InvalidInputError(f"{name}: contains NaN or inf")
        if (w < 0).any():
            raise InvalidInputError("weights: must be non-negative")
        total = w.sum(-1)
        if not torch.allclose(total, torch.ones_like(total), atol=WEIGHT_SUM_ATOL, rtol=0):
            worst = float((total - 1).abs().max())
            raise InvalidInputError(
                f"weights: must sum to 1 over the last axis (worst deviation {worst:.3g})"
            )
        lower = torch.tril(u, diagonal=-1)
        if (lower != 0).any():
            raise InvalidInputError(
                "precision_cholesky: must be upper triangular (entries below the diagonal are non-zero)"
            )
        diag = torch.diagonal(u, dim1=-2, dim2=-1)
        if (diag <= 0).any():
            raise InvalidInputError(
                "precision_cholesky: diagonal must be positive (the precision must be positive definite); "
                f"smallest diagonal entry {float(diag.min()):.3g}"
            )

    # ------------------------------------------------------------ properties
    @property
    def batch_shape(self) -> torch.Size:
        return self.weights.shape[:-1]

    @property
    def n_components(self) -> int:
        return self.weights.shape[-1]

    @property
    def dim(self) -> int:
        return self.means.shape[-1]

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
        if x.ndim < 2 or x.shape[-1] != self.dim:
            raise InvalidInputError(
                f"points: expected shape (..., N, {self.dim}) for a {self.dim}-D mixture, got {tuple(x.shape)}"
            )
        try:
            torch.broadcast_shapes(x.shape[:-2], self.batch_shape)
        except RuntimeError as exc:
            raise InvalidInputError(
                f"points: leading shape {tuple(x.shape[:-2])} does not broadcast against the batch shape "
                f"{tuple(self.batch_shape)}"
            ) from exc
        if not torch.isfinite(x).all():
            raise InvalidInputError("points: contain NaN or inf")
        return x.to(self.dtype)

    def component_log_prob(self, points) -> torch.Tensor:
        """``log N(x_n; mu_k, Sigma_k)`` for points ``(..., N, d)``; returns ``(..., K, N)``.

        Raises :class:`InvalidInputError` for points of the wrong dimension or type, a leading
        shape that does not broadcast against the batch shape, or NaN/inf values.
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
        """Mixture log density (eq. 1) of points ``(..., N, d)``; returns ``(..., N)``.

        Stable for far-away points: the sum over components is a log-sum-exp.
        Zero-weight components contribute ``-inf`` inside the log-sum-exp and are ignored.
        """
        comp = self.component_log_prob(points)
        logw = torch.log(self.weights).unsqueeze(-1)
        return torch.logsumexp(logw + comp, dim=-2)

    def sample(self, n: int, seed=None) -> torch.Tensor:
        """Draw ``n`` points from each mixture; returns ``(..., n, d)``.

        ``seed``: ``None``, an int or a ``torch.Generator``.
        """
        if n < 0:
            raise InvalidInputError(f"n: expected >= 0, got {n}")
        gen = (
            seed
            if isinstance(seed, torch.Generator)
            else torch.Generator().manual_seed(
                int(np.random.SeedSequence(seed).generate_state(1)[0])
                if seed is None or isinstance(seed, (int, np.integer))
                else int(seed)
            )
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
        """Like ``torch.Tensor.to`` (dtype and/or device) for all parameters."""
        return GaussianMixture(
            self.weights.to(*args, **kwargs),
            self.means.to(*args, **kwargs),
            self.precision_cholesky.to(*args, **kwargs),
            validate=False,
        )

    def detach(self) -> GaussianMixture:
        return GaussianMixture(
            self.weights.detach(),
            self.means.detach(),
            self.precision_cholesky.detach(),
            validate=False,
        )

    def numpy(self) -> dict[str, np.ndarray]:
        """``{"weights", "means", "precision_cholesky"}`` as NumPy arrays (detached, on CPU)."""
        return {
            k: getattr(self, k).detach().cpu().numpy()
            for k in ("weights", "means", "precision_cholesky")
        }

    @classmethod
    def from_numpy(
        cls, weights, means, precision_cholesky, *, validate: bool = True
    ) -> GaussianMixture:
        return cls(
            np.asarray(weights),
            np.asarray(means),
            np.asarray(precision_cholesky),
            validate=validate,
        )

    @classmethod
    def from_covariances(
        cls, weights, means, covariances, *, validate: bool = True
    ) -> GaussianMixture:
        """Build from covariances ``(..., K, d, d)``: ``U = chol(Sigma^{-1})^T``."""
        cov = _as_tensor(covariances)
        if validate and not torch.isfinite(cov).all():
            raise InvalidInputError("covariances: contains NaN or inf")
        try:
            prec = torch.linalg.inv(cov)
            lower = torch.linalg.cholesky((prec + prec.transpose(-1, -2)) / 2)
        except RuntimeError as exc:  # torch raises _LinAlgError (a RuntimeError)
            raise InvalidInputError(
                f"covariances: not symmetric positive definite ({exc})"
            ) from exc
        return cls(weights, means, lower.transpose(-1, -2), validate=validate)

    def __getitem__(self, idx) -> GaussianMixture:
        """Index the batch axes: ``gm[3]``, ``gm[:, 0]``."""
        if not isinstance(idx, tuple):
            idx = (idx,)
        if Ellipsis in idx:
            raise InvalidInputError(
                "GaussianMixture indexing: Ellipsis is not supported; index batch axes explicitly"
            )
        if len(idx) > len(self.batch_shape):
            raise InvalidInputError(f"too many indices for batch shape {tuple(self.batch_shape)}")
        return GaussianMixture(
            self.weights[idx], self.means[idx], self.precision_cholesky[idx], validate=False
        )

    def __repr__(self) -> str:
        return (
            f"GaussianMixture(batch_shape={tuple(self.batch_shape)}, K={self.n_components}, d={self.dim}, "
            f"dtype={self.dtype})"
        )


def _as_tensor(x) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x
    arr = np.asarray(x)
    if arr.dtype.kind not in "fiu":
        raise InvalidInputError(f"expected a numeric array, got dtype {arr.dtype}")
    return torch.as_tensor(arr, dtype=torch.float64 if arr.dtype.kind in "iu" else None)
