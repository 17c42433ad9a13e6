"""Probability of collision for Gaussians and Gaussian mixtures against obstacles
(MDN paper section V, eqs. 8-10, extending Patil, van den Berg, Alterovitz, ICRA 2012;
deformable-planning paper section IV-D for 2-D states among tissue obstacles).

One core serves 3-D triangle meshes and 2-D polygons:

>>> from riskplan.gaussian_mixture import NumpyMixture
>>> env = Environment.from_polygons([[[1, -1], [2, -1], [2, 1], [1, 1]]])
>>> gm = NumpyMixture.from_covariances([1.0], [[0.0, 0.0]], [np.eye(2) * 0.25])
>>> float(probability_of_collision(gm, env))  # 1 - Phi(2): the mean is 2 sigma from the box
0.0227...

Mixtures are :class:`~riskplan.gaussian_mixture.NumpyMixture` batches or the torch
:class:`riskplan.kinematics.GaussianMixture` the MDN predicts (converted by its
``to_numpy()``); this package never imports torch itself.
"""

from __future__ import annotations

import numpy as np

from riskplan.collision.environment import Environment
from riskplan.collision.gaussian import (
    DEFAULT_CUTOFF,
    FreeRegion,
    free_region,
    gaussian_bound,
    gaussian_bound_covariance,
    gaussian_bound_terms,
    precision_cholesky_from_covariance,
)
from riskplan.collision.geometry import mahalanobis, unwhiten, whiten
from riskplan.collision.mesh_files import (
    BasePose,  # noqa: F401 - riskplan.robots.BasePose, importable here too (documented there)
    environment_in_base_frame,
    load_environment,
    mesh_base_pose,
    save_environment,
)
from riskplan.collision.mixture_bounds import COMBINES, component_bounds, mixture_bound
from riskplan.collision.montecarlo import (
    MonteCarloEstimate,
    binomial_interval,
    monte_carlo_probability,
    monte_carlo_trajectory,
    paths_collide,
)
from riskplan.collision.trajectory import trajectory_bound, trajectory_probability
from riskplan.errors import InvalidInputError

METHODS = ("bound", "union", "monte_carlo", "monte_carlo_union")


def probability_of_collision(
    mixture,
    environment: Environment,
    method: str = "bound",
    *,
    cutoff: float = DEFAULT_CUTOFF,
    n_samples: int = 10_000,
    seed=None,
    validate: bool = True,
) -> np.ndarray:
    r"""Collision probability of a mixture batch.

    ``method``:

    * ``"bound"`` — eq. 9 of the MDN paper, an upper bound on the probability that a point drawn
      from the geometry distribution lies outside free space:

      .. math:: P(\text{collision}) \le \sum_i w_i \sum_j \bigl(1 - \Phi(b_{ij})\bigr)

    * ``"union"`` — ``min(1, sum_i sum_j (1 - Phi(b_ij)))``: ignores the weights; bounds the
      probability that any of the components (one point from each) is in collision.
    * ``"monte_carlo"`` / ``"monte_carlo_union"`` — sampling estimates of the two quantities
      (``n_samples``, ``seed``); use :func:`monte_carlo_probability` for intervals.

    Parameters
    ----------
    mixture : NumpyMixture or GaussianMixture
        A :class:`~riskplan.gaussian_mixture.NumpyMixture` with batch shape ``(...)``, ``K``
        components in ``d`` dimensions, or a torch :class:`~riskplan.kinematics.GaussianMixture`
        (converted by its ``to_numpy()``).
    environment : Environment
        Obstacles of the same dimension ``d``, in the mixture's frame.
    method : str
        One of :data:`METHODS` (above).
    cutoff : float
        Whitened radius beyond which faces are not visited (:func:`gaussian_bound`).
    n_samples : int
        Draws per mixture for the sampling methods.
    seed : int, numpy.random.Generator or None
        Seed of the sampling methods.
    validate : bool
        Check the mixture's shapes and values (skip for inputs checked already).

    Returns
    -------
    numpy.ndarray, (...,)
        Probabilities (or bounds) in [0, 1].
    """
    if method == "bound":
        return mixture_bound(
            mixture, environment, combine="weighted", cutoff=cutoff, validate=validate
        )
    if method == "union":
        return mixture_bound(
            mixture, environment, combine="union", cutoff=cutoff, validate=validate
        )
    if method in ("monte_carlo", "monte_carlo_union"):
        combine = "weighted" if method == "monte_carlo" else "union"
        return monte_carlo_probability(
            mixture, environment, n_samples, combine=combine, seed=seed, validate=validate
        ).probability
    raise InvalidInputError(f"method: expected one of {METHODS}, got {method!r}")


__all__ = [
    "COMBINES",
    "DEFAULT_CUTOFF",
    "METHODS",
    "Environment",
    "FreeRegion",
    "MonteCarloEstimate",
    "binomial_interval",
    "component_bounds",
    "environment_in_base_frame",
    "free_region",
    "gaussian_bound",
    "gaussian_bound_covariance",
    "gaussian_bound_terms",
    "load_environment",
    "mahalanobis",
    "mesh_base_pose",
    "mixture_bound",
    "monte_carlo_probability",
    "monte_carlo_trajectory",
    "paths_collide",
    "precision_cholesky_from_covariance",
    "probability_of_collision",
    "save_environment",
    "trajectory_bound",
    "trajectory_probability",
    "unwhiten",
    "whiten",
]
