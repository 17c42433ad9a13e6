"""Gaussian mixtures over a continuum robot's geometry built from backbone curves.

The MDN (MDN paper section III) learns such mixtures from point clouds; this module gives
the same kind of object directly from a backbone curve (from the Cosserat model or a
constant-curvature arc), for callers without a trained model and for reference cases.

Component ``k`` covers the ``k``-th of ``K`` equal arc-length pieces of the backbone:
its mean is the mean backbone point of the piece, its covariance is the spread of those
points along the piece plus the cross-section spread of the body (points on disks of radius
``radius`` around the backbone: variance ``radius^2 / 2`` per direction normal to the
tangent, ``radius^2 / 4`` for a uniform disk; we use ``radius^2 / 4``) plus an isotropic
``sigma^2`` for shape uncertainty. Weights are equal.

:func:`backbone_numpy_mixture` and :func:`robot_numpy_mixture` return the torch-free
:class:`~riskplan.gaussian_mixture.NumpyMixture`; :func:`backbone_mixture` and
:func:`robot_mixture` return the same mixture as a torch
:class:`riskplan.kinematics.GaussianMixture` (torch is imported only when they are called).
"""

from __future__ import annotations

import numpy as np

from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import NumpyMixture


def arc_backbone(curvature, bend_angle, length: float = 0.2, n: int = 41) -> np.ndarray:
    """Constant-curvature backbone ``(..., n, 3)`` in the base frame (z = tangent at s = 0).

    ``curvature`` (1/m) and ``bend_angle`` (rad, direction of bending in the base x-y plane)
    broadcast against each other.
    """
    k = np.asarray(curvature, dtype=np.float64)[..., None]
    phi = np.asarray(bend_angle, dtype=np.float64)[..., None]
    k, phi = np.broadcast_arrays(k, phi)
    s = np.linspace(0.0, length, n)
    small = np.abs(k) < 1e-9
    ks = np.where(small, 1.0, k)
    r = np.where(small, 0.5 * k * s * s, (1 - np.cos(ks * s)) / ks)
    z = np.where(small, s, np.sin(ks * s) / ks)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z + 0 * r], axis=-1)


def backbone_numpy_mixture(
    positions, n_components: int = 5, *, radius: float = 0.01, sigma: float = 0.003
) -> NumpyMixture:
    """Gaussian mixture ``(..., K)`` over the body around backbone points ``positions (..., n, 3)``.

    Returns a :class:`~riskplan.gaussian_mixture.NumpyMixture` (float64, d = 3).
    """
    P = np.asarray(positions, dtype=np.float64)
    if P.ndim < 2 or P.shape[-1] != 3 or P.shape[-2] < 2 * n_components:
        raise InvalidInputError(
            f"positions: expected shape (..., n >= {2 * n_components}, 3), got {P.shape}"
        )
    if not np.all(np.isfinite(P)):
        raise InvalidInputError("positions: contain NaN or inf")
    if radius < 0 or sigma <= 0:
        raise InvalidInputError(f"radius >= 0 and sigma > 0 required, got {radius}, {sigma}")
    n = P.shape[-2]
    edges = np.linspace(0, n - 1, n_components + 1)
    means, covs = [], []
    eye = np.eye(3)
    for k in range(n_components):
        i0, i1 = int(np.floor(edges[k])), int(np.ceil(edges[k + 1]))
        seg = P[..., i0 : i1 + 1, :]
        mu = seg.mean(-2)
        dev = seg - mu[..., None, :]
        cov = np.einsum("...ni,...nj->...ij", dev, dev) / seg.shape[-2]
        t = seg[..., -1, :] - seg[..., 0, :]
        t = t / np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-12)
        normal_proj = eye - t[..., :, None] * t[..., None, :]
        cov = cov + (radius**2 / 4) * normal_proj + sigma**2 * eye
        means.append(mu)
        covs.append(cov)
    means = np.stack(means, axis=-2)
    covs = np.stack(covs, axis=-3)
    w = np.full(means.shape[:-1], 1.0 / n_components)
    return NumpyMixture.from_covariances(w, means, covs)


def robot_numpy_mixture(
    robot, displacements, n_components: int = 5, *, radius: float = 0.01, sigma: float = 0.003
) -> NumpyMixture:
    """Mixture over the body of ``robot`` at tendon ``displacements (..., m)``.

    Uses the robot's deterministic model (``robot.solve_displacements(d).positions``, base frame)
    and :func:`backbone_numpy_mixture`; a stand-in for a trained MDN when none is available.
    """
    d = np.asarray(displacements, dtype=np.float64)
    shape = robot.solve_displacements(d)
    return backbone_numpy_mixture(
        np.asarray(shape.positions, dtype=np.float64), n_components, radius=radius, sigma=sigma
    )


def backbone_mixture(
    positions, n_components: int = 5, *, radius: float = 0.01, sigma: float = 0.003
):
    """:func:`backbone_numpy_mixture` as a torch :class:`riskplan.kinematics.GaussianMixture`."""
    return _torch_mixture(
        backbone_numpy_mixture(positions, n_components, radius=radius, sigma=sigma)
    )


def robot_mixture(
    robot, displacements, n_components: int = 5, *, radius: float = 0.01, sigma: float = 0.003
):
    """:func:`robot_numpy_mixture` as a torch :class:`riskplan.kinematics.GaussianMixture`."""
    return _torch_mixture(
        robot_numpy_mixture(robot, displacements, n_components, radius=radius, sigma=sigma)
    )


def _torch_mixture(mixture: NumpyMixture):
    from riskplan.kinematics import GaussianMixture

    return GaussianMixture.from_numpy_mixture(mixture)
