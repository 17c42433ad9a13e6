"""The needle scenario's reduced-state frames (:mod:`riskplan.scenarios.needle`, module
docstring, "Reduced state, two frames"): what the controller and LQG-MP see of a state in the
world or the material frame — the reduced state, the measurement and its Jacobian, the
obstacles and the goal in the reduced state's coordinates.

The functions take the scenario as ``self``: :class:`~riskplan.scenarios.needle.NeedleScenario`
binds them as its methods (``reduced``, ``measure``,
``observation_jacobian``, ``state_obstacles``, ``state_goal``, ``observe``), documented
there."""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array
from riskplan.scenarios.base import SimParams, gaussian_noise
from riskplan.scenarios.needle_config import NeedleState

__all__: list[str] = []

#: Step of the central differences of :meth:`NeedleScenario.observation_jacobian`, in
#: units of the scene size: far below an element (about 0.1 on the planning mesh), so a
#: difference straddles an element edge (where the P1 field has a kink) only for a pose
#: within 1e-6 of it.
H_STEP = 1e-6


def reduced(self, state: NeedleState) -> np.ndarray:
    """The reduced state ``x`` of ``state`` (paper section III) in ``self.frame``.

    Parameters
    ----------
    state : NeedleState

    Returns
    -------
    numpy.ndarray, shape (3,)
        A copy: the world pose ``(x, y, θ)`` (``frame="world"``) or the material pose
        ``(X, Y, Θ)`` (``frame="material"``); lengths in scene units, angles in rad.
    """
    return np.array(state.pose if self.frame == "world" else state.material)


def measure(self, state: NeedleState, noise=None, rng=None) -> np.ndarray:
    """``z = (x, y) + n``, the sensed world position of the robot in ``state`` (both
    frames; in the world frame equal to ``observe(reduced(state))``).

    Parameters
    ----------
    state : NeedleState
    noise : array_like, shape (2,), optional
        ``n`` given explicitly; else drawn from ``N(0, σ² I)`` with ``rng``.
    rng : int, numpy.random.Generator or None
        Draws ``n``; zero noise if neither ``noise`` nor ``rng`` is given.

    Returns
    -------
    numpy.ndarray, shape (2,)
    """
    return np.array(state.pose[:2]) + gaussian_noise(self.sensing_cov, noise, rng, 2)


def observation_jacobian(self, state: NeedleState, params: SimParams | None = None) -> np.ndarray:
    """``H`` of the measurement at ``state`` with respect to the reduced state.

    World frame: the constant ``[I₂ 0]``. Material frame: the Jacobian of
    ``h = X + u(X; Θ, s)`` (:mod:`riskplan.scenarios.needle`) by central differences with step
    :data:`H_STEP`, the tissue's response recomputed at each perturbed material pose:
    ``u`` depends on the pose both through where the interpolation reads it and through
    where and in which direction the robot pushes.

    .. math::

        H_{:,k} = \\frac{h(x + \\epsilon e_k) - h(x - \\epsilon e_k)}{2 \\epsilon},
        \\qquad x = (X, Y, \\Theta)

    Parameters
    ----------
    state : NeedleState
    params : SimParams, optional
        ``s`` (default: the nominal parameters).

    Returns
    -------
    numpy.ndarray, shape (2, 3)
        ``[I₂ 0]`` in the world frame and for a robot outside the tissue (nothing moves
        it).
    """
    if self.frame == "world":
        return np.array(self.observation_matrix)
    params = params or self.nominal_params
    mat = np.asarray(state.material, dtype=np.float64)
    return self.model(params).position_jacobian(mat, params.force_scale, H_STEP)


def state_obstacles(self, state: NeedleState) -> list[np.ndarray]:
    """The obstacles in the reduced state's coordinates (what LQG-MP checks ``x``
    against).

    Parameters
    ----------
    state : NeedleState

    Returns
    -------
    list of numpy.ndarray, each shape (k_i, 2)
        The deformed polygons of ``state`` (world frame, :meth:`obstacles`) or the
        reference polygons of material points (material frame).
    """
    if self.frame == "world":
        return self.obstacles(state)
    return [np.array(p) for p in self.config.obstacles]


def state_goal(self, state: NeedleState) -> np.ndarray:
    """The goal polygon in the reduced state's coordinates.

    Parameters
    ----------
    state : NeedleState

    Returns
    -------
    numpy.ndarray, shape (24, 2)
        World frame: the deformed goal (:meth:`goal`); material frame: the reference
        goal disk's 24-gon.
    """
    if self.frame == "world":
        return self.goal(state)
    return np.array(self.config.goal_polygon)


def observe(self, x, noise=None, rng=None) -> np.ndarray:
    """``z = H x + n`` (paper eq. 3), ``H = [I₂ 0]``: position only, for the world
    frame's reduced state (in the material frame the measurement is not linear in
    ``x``: :meth:`measure`).

    Parameters
    ----------
    x : array_like, shape (3,)
        Reduced state ``(x, y, θ)``.
    noise : array_like, shape (2,), optional
        ``n`` given explicitly; else drawn from ``N(0, σ² I)`` with ``rng``.
    rng : int, numpy.random.Generator or None
        Draws ``n``; zero noise if neither ``noise`` nor ``rng`` is given.

    Returns
    -------
    numpy.ndarray, shape (2,)
    """
    x = as_array(x, "x", shape=(3,))
    return self.observation_matrix @ x + gaussian_noise(self.sensing_cov, noise, rng, 2)
