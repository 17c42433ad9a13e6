r"""Collision probability bounds of Gaussian mixtures (MDN paper section V, eq. 9).

Mixtures are :class:`~riskplan.gaussian_mixture.NumpyMixture` batches; a torch
:class:`riskplan.kinematics.GaussianMixture` is accepted too and converted by its
``to_numpy()``. Nothing here imports torch.

Two quantities, side by side:

``combine="weighted"`` (the paper's eq. 9)
    .. math::

        p(x \notin X_f) \le \sum_{i=1}^{N} w_i \sum_{j=1}^{K_i} \left(1 - \Phi(b_{ij})\right)

    This bounds the probability that ONE point drawn
    from the geometry distribution (pick component ``i`` with probability ``w_i``, then a point
    from it) lies outside free space. It is not the probability that any part of the robot
    collides: a robot whose mixture puts weight 0.2 on a tip component that surely collides gets
    about 0.2, not 1.

``combine="union"`` (stricter; ignores the weights)
    ``P <= min(1, sum_i sum_j (1 - Phi(b_ij)))``: by Boole's inequality, a bound on the
    probability that at least one of K points, one drawn from each component (any joint law),
    is in collision. Use it when each component stands for a part of the robot that must
    all be free ("any part of the robot").

Each component's sum is first capped at 1 (a probability), which keeps both bounds valid and
never loosens them. Components whose mean is in collision contribute 1.
"""

from __future__ import annotations

import numpy as np

from riskplan.collision.environment import Environment, check_environment
from riskplan.collision.gaussian import DEFAULT_CUTOFF, gaussian_bound_terms
from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import NumpyMixture, as_numpy_mixture

COMBINES = ("weighted", "union")


def check_mixture(mixture, d: int, *, validate: bool = True) -> NumpyMixture:
    """``mixture`` as a :class:`~riskplan.gaussian_mixture.NumpyMixture` of dimension ``d``.

    Accepts a ``NumpyMixture`` or a torch :class:`riskplan.kinematics.GaussianMixture`
    (converted by its ``to_numpy()``); re-validated when ``validate``.
    """
    out = as_numpy_mixture(mixture, validate=validate)
    if out.dim != d:
        raise InvalidInputError(
            f"mixture: dimension {out.dim} does not match the {d}-D environment"
        )
    return out


def component_bounds(
    mixture, environment: Environment, *, cutoff: float = DEFAULT_CUTOFF, validate: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    r"""Per-component bounds :math:`p_i = \min(1, \sum_j (1 - \Phi(b_{ij})))` and the weights.

    Parameters
    ----------
    mixture : NumpyMixture or GaussianMixture
        Batch of mixtures with ``K`` components.
    environment : Environment
        Obstacles in the mixture's frame.
    cutoff : float
        Whitened radius beyond which faces are not visited (module :mod:`riskplan.collision.gaussian`).
    validate : bool
        Check the arguments.

    Returns
    -------
    bounds : numpy.ndarray
        ``(..., K)``.
    weights : numpy.ndarray
        ``(..., K)``.
    """
    check_environment(environment)
    gm = check_mixture(mixture, environment.dim, validate=validate)
    terms = gaussian_bound_terms(
        gm.means, gm.precision_cholesky, environment, cutoff=cutoff, validate=validate
    )
    return terms.bound, gm.weights


def mixture_bound(
    mixture,
    environment: Environment,
    *,
    combine: str = "weighted",
    cutoff: float = DEFAULT_CUTOFF,
    validate: bool = True,
) -> np.ndarray:
    r"""Upper bound on the collision probability of a mixture batch (MDN paper eq. 9).

    ``combine="weighted"``: eq. 9, the probability that a point drawn from the mixture is
    outside free space,

    .. math::

        \sum_i w_i \min\left(1, \sum_j (1 - \Phi(b_{ij}))\right);

    ``combine="union"``: :math:`\min(1, \sum_i \min(1, \sum_j (1 - \Phi(b_{ij}))))`, any of
    the components' points (module docstring).

    Parameters
    ----------
    mixture : NumpyMixture or GaussianMixture
        Batch of mixtures.
    environment : Environment
        Obstacles in the mixture's frame.
    combine : {"weighted", "union"}
        Which quantity.
    cutoff : float
        Whitened radius beyond which faces are not visited.
    validate : bool
        Check the arguments.

    Returns
    -------
    numpy.ndarray
        ``(...,)`` in ``[0, 1]``.
    """
    if combine not in COMBINES:
        raise InvalidInputError(f"combine: expected one of {COMBINES}, got {combine!r}")
    check_environment(environment)
    p, w = component_bounds(mixture, environment, cutoff=cutoff, validate=validate)
    out = (w * p).sum(-1) if combine == "weighted" else p.sum(-1)
    return np.clip(out, 0.0, 1.0)
