r"""Collision probability along a trajectory (MDN paper section V, eq. 10).

``combine="independent"`` (eq. 10):

.. math::

    p(\exists x \in \tau : x \notin X_f) \le 1 - \prod_{x \in \tau} \left(1 - p(x \notin X_f)\right).

This treats the per-state events as independent; it is what the paper optimises.
``combine="union"``: ``min(1, sum_t p_t)`` (Boole), an upper bound whatever the dependence
between states; it is never smaller than the eq. 10 value.
"""

from __future__ import annotations

import numpy as np

from riskplan.collision.environment import Environment
from riskplan.collision.gaussian import DEFAULT_CUTOFF
from riskplan.collision.mixture_bounds import mixture_bound
from riskplan.errors import InvalidInputError

TRAJECTORY_COMBINES = ("independent", "union")


def trajectory_probability(
    probabilities, *, combine: str = "independent", axis: int = -1
) -> np.ndarray:
    r"""Combine per-state probabilities into the probability of a trajectory.

    ``independent``: :math:`1 - \prod_t (1 - p_t)` (eq. 10), computed as
    ``-expm1(sum log1p(-p_t))`` for accuracy at small ``p``. ``union``:
    :math:`\min(1, \sum_t p_t)`.

    Parameters
    ----------
    probabilities : array_like
        ``(..., T)`` per-state probabilities in ``[0, 1]`` (states along ``axis``).
    combine : {"independent", "union"}
        The rule.
    axis : int
        The axis of the states.

    Returns
    -------
    numpy.ndarray
        ``(...,)`` in ``[0, 1]``.
    """
    p = np.asarray(probabilities, dtype=np.float64)
    if p.ndim == 0:
        raise InvalidInputError("probabilities: expected at least one axis (states)")
    if not np.all(np.isfinite(p)) or np.any((p < 0) | (p > 1)):
        raise InvalidInputError("probabilities: must be finite and in [0, 1]")
    if combine == "independent":
        with np.errstate(divide="ignore"):
            out = -np.expm1(np.log1p(-p).sum(axis=axis))
    elif combine == "union":
        out = p.sum(axis=axis)
    else:
        raise InvalidInputError(f"combine: expected one of {TRAJECTORY_COMBINES}, got {combine!r}")
    return np.clip(out, 0.0, 1.0)


def trajectory_bound(
    mixtures,
    environment: Environment,
    *,
    combine: str = "independent",
    mixture_combine: str = "weighted",
    cutoff: float = DEFAULT_CUTOFF,
    validate: bool = True,
) -> np.ndarray:
    """Eq. 10 over eq. 9: the bound of a trajectory of mixtures.

    Parameters
    ----------
    mixtures : NumpyMixture or GaussianMixture
        Batch shape ``(..., T)``, the states along the last batch axis.
    environment : Environment
        Obstacles in the mixtures' frame.
    combine : {"independent", "union"}
        Along the trajectory (:func:`trajectory_probability`).
    mixture_combine : {"weighted", "union"}
        Per state (:func:`~riskplan.collision.mixture_bound`).
    cutoff : float
        Whitened radius beyond which faces are not visited.
    validate : bool
        Check the arguments.

    Returns
    -------
    numpy.ndarray
        ``(...,)`` in ``[0, 1]``.
    """
    p = mixture_bound(
        mixtures, environment, combine=mixture_combine, cutoff=cutoff, validate=validate
    )
    if p.ndim == 0:
        raise InvalidInputError("mixtures: expected a batch axis of states (batch shape (..., T))")
    return trajectory_probability(p, combine=combine)
