r"""The kinematics-model seam: what the chest planner asks of a robot's model.

A *kinematics model* maps configurations of a robot to the distribution of its body's points,
a Gaussian mixture (MDN paper, eq. 1). The learned :class:`~riskplan.kinematics.MDNModel` is
one; a robot type of another kind (an analytic continuum model, a model learned elsewhere)
plugs into the kinematic wing's planner (``riskplan.planning.plan_chest``,
``riskplan.planning.plan_robot``: the PRM, the eq.-9/10 risk and the Bayesian optimisation)
by providing the two members of :class:`KinematicsModel`; nothing in ``riskplan.planning`` names
the model's type.

The contract
------------
``limits``
    ``(m, 2)`` array of the lower and upper bound of each of the ``m`` inputs (the box the
    planner samples and the optimiser stays in). Units are the model's own; the planner's
    ``step`` and ``resolution`` measure distances in these units (metres of tendon
    displacement for the MDN), so they should be of the order of the box's sides.
``predict(configurations)``
    ``configurations``: ``(N, m)`` float64 array within ``limits``. Returns the body's
    distribution at each configuration: a mixture with batch shape ``(N,)``, ``K`` components
    in 3 dimensions -- a :class:`~riskplan.gaussian_mixture.NumpyMixture`, or anything
    :func:`~riskplan.gaussian_mixture.as_numpy_mixture` converts (the torch
    :class:`~riskplan.kinematics.GaussianMixture`). Points are in metres, in the frame of the
    obstacles the planner is given (the robot's base frame for the chest). A point drawn from
    the mixture is a point of the robot's body (MDN paper eq. 1); the planner's validity test
    asks that every component mean lies outside every obstacle, eq. 9 bounds the probability
    that a drawn point lies inside one:

    .. math:: p(x \mid q) = \sum_{k=1}^{K} w_k(q)\, \mathcal{N}(x; \mu_k(q), \Sigma_k(q))

    The predicted tip (for a ``goal_tip``) is the component mean farthest from the frame's
    origin. ``predict`` must be deterministic: the optimiser compares bounds across calls.

Optional members the planner uses where present: ``robot`` (a
:class:`~riskplan.robots.TendonRobot`: the body-contact risk ``risk="bodies"``, the planning
weights of base rotation) and ``n_tendons``.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import as_numpy_mixture

__all__ = ["KinematicsModel", "check_kinematics_model"]


@runtime_checkable
class KinematicsModel(Protocol):
    """What a robot's kinematics model provides to the planner (see the module docs).

    ``isinstance(obj, KinematicsModel)`` tests that ``obj`` has both members;
    :func:`check_kinematics_model` also checks their values.

    Attributes
    ----------
    limits : numpy.ndarray, shape (m, 2)
        Lower and upper bound of each input, in the model's input units.
    """

    limits: np.ndarray

    def predict(self, configurations):
        """The body's distribution at configurations.

        Parameters
        ----------
        configurations : numpy.ndarray, shape (N, m)
            Inputs within ``limits`` (float64).

        Returns
        -------
        NumpyMixture or GaussianMixture
            Batch shape ``(N,)``, ``K`` components in 3 dimensions; points in metres, in the
            obstacles' frame.
        """


def check_kinematics_model(model, name: str = "model") -> np.ndarray:
    """Check that ``model`` is a :class:`KinematicsModel` and return its limits.

    The members must exist, ``limits`` must be a finite ordered ``(m, 2)`` box with ``m >= 1``,
    and ``predict`` at the box's centre must return a mixture of batch shape ``(1,)`` in 3
    dimensions (one prediction, so that a wrong model fails here, named, before any planning).

    Parameters
    ----------
    model : object
        The candidate model.
    name : str
        The argument's name in error messages.

    Returns
    -------
    numpy.ndarray, shape (m, 2)
        The limits as float64.

    Raises
    ------
    InvalidInputError
        A member missing, malformed limits or a prediction of the wrong kind.
    """
    lim = _checked_limits(model, name)
    probe = lim.mean(axis=1)[None]
    try:
        gm = as_numpy_mixture(model.predict(probe))
    except InvalidInputError as e:
        raise InvalidInputError(f"{name}.predict: at the box's centre, {e}") from e
    if gm.batch_shape != (1,) or gm.dim != 3:
        raise InvalidInputError(
            f"{name}.predict: for configurations (1, {len(lim)}) expected a mixture of batch "
            f"shape (1,) in 3 dimensions, got batch shape {gm.batch_shape}, dimension {gm.dim}"
        )
    return lim


def _checked_limits(model, name: str = "model") -> np.ndarray:
    """The members and limits checks of ``check_kinematics_model``, without its prediction.

    For a caller that needs the limits before handing the model on to a planner that makes the
    full check (``plan_chest``'s default goal), so that the model is predicted once.

    Parameters
    ----------
    model : object
        The candidate model.
    name : str
        The argument's name in error messages.

    Returns
    -------
    numpy.ndarray, shape (m, 2)
        The limits as float64.

    Raises
    ------
    InvalidInputError
        A member missing or malformed limits.
    """
    missing = [m for m in ("limits", "predict") if not hasattr(model, m)]
    if missing or not callable(model.predict):
        lacks = ", ".join(missing) if missing else "a callable predict"
        raise InvalidInputError(
            f"{name}: expected a kinematics model (predict(configurations (N, m)) -> mixture "
            f"and limits (m, 2)); {type(model).__name__} lacks {lacks}"
        )
    try:
        lim = np.asarray(model.limits, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InvalidInputError(f"{name}.limits: expected an (m, 2) array of numbers ({e})") from e
    if lim.ndim != 2 or lim.shape[1] != 2 or lim.shape[0] < 1:
        raise InvalidInputError(f"{name}.limits: expected shape (m, 2), got {lim.shape}")
    if not np.all(np.isfinite(lim)) or np.any(lim[:, 0] > lim[:, 1]):
        raise InvalidInputError(
            f"{name}.limits: expected finite bounds with lower <= upper, got {lim.tolist()}"
        )
    return lim
