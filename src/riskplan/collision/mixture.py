"""Collision probability of a Gaussian mixture (MDN paper section V, eq. 9).

Two quantities, side by side:

``combine="weighted"`` (the paper's eq. 9)
    ``P <= sum_i w_i sum_j (1 - Phi(b_ij))``. This bounds the probability that ONE point drawn
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

COMBINES = ("weighted", "union")


def mixture_arrays(
    mixture, d: int, *, validate: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(weights (..., K), means (..., K, d), U (..., K, d, d))`` as float64 NumPy arrays.

    ``mixture`` is a :class:`riskplan.kinematics.GaussianMixture` (re-validated when ``validate``).
    """
    if not all(hasattr(mixture, a) for a in ("weights", "means", "precision_cholesky")):
        raise InvalidInputError(
            f"mixture: expected a GaussianMixture, got {type(mixture).__name__}"
        )
    if validate and hasattr(mixture, "validate"):
        mixture.validate()
    arrs = (
        mixture.numpy()
        if hasattr(mixture, "numpy")
        else {
            k: np.asarray(getattr(mixture, k)) for k in ("weights", "means", "precision_cholesky")
        }
    )
    w = np.asarray(arrs["weights"], dtype=np.float64)
    m = np.asarray(arrs["means"], dtype=np.float64)
    u = np.asarray(arrs["precision_cholesky"], dtype=np.float64)
    if m.shape[-1] != d:
        raise InvalidInputError(
            f"mixture: dimension {m.shape[-1]} does not match the {d}-D environment"
        )
    return w, m, u


def component_bounds(
    mixture, environment: Environment, *, cutoff: float = DEFAULT_CUTOFF, validate: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Per-component bounds ``p_i = min(1, sum_j (1 - Phi(b_ij)))`` and weights; both ``(..., K)``."""
    check_environment(environment)
    w, m, u = mixture_arrays(mixture, environment.dim, validate=validate)
    terms = gaussian_bound_terms(m, u, environment, cutoff=cutoff, validate=validate)
    return terms.bound, w


def mixture_bound(
    mixture,
    environment: Environment,
    *,
    combine: str = "weighted",
    cutoff: float = DEFAULT_CUTOFF,
    validate: bool = True,
) -> np.ndarray:
    """Upper bound on the collision probability of a mixture batch; returns ``(...,)`` in [0, 1].

    ``combine="weighted"``: eq. 9, ``sum_i w_i min(1, sum_j (1 - Phi(b_ij)))`` — probability that
    a point drawn from the mixture is outside free space. ``combine="union"``:
    ``min(1, sum_i min(1, sum_j (1 - Phi(b_ij))))`` — any of the components' points (see module
    docstring).
    """
    if combine not in COMBINES:
        raise InvalidInputError(f"combine: expected one of {COMBINES}, got {combine!r}")
    check_environment(environment)
    p, w = component_bounds(mixture, environment, cutoff=cutoff, validate=validate)
    out = (w * p).sum(-1) if combine == "weighted" else p.sum(-1)
    return np.clip(out, 0.0, 1.0)
