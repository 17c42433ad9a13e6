"""The geometry of a manipulation state (:mod:`riskplan.scenarios.manipulation`): where the
target, the sensed boundary points and the manipulators are, the deformed outline and the body
LQG-MP checks against the obstacle, and the collision and goal tests.

The functions take the scenario as ``self``:
:class:`~riskplan.scenarios.manipulation.ManipulationScenario` binds them as its methods
(``target``, ``boundary_points``, ``manipulator_positions``, ``outline``, ``obstacles``,
``goal``, ``collision_outline``, ``in_collision``, ``in_goal``, ``goal_distance``, ``path``),
documented there."""

from __future__ import annotations

import numpy as np

from riskplan import geometry2d as geo

# the scenario's methods: handed out by no package
__all__: list[str] = []


def target(self, state) -> np.ndarray:
    """Current position of the internal target point.

    Parameters
    ----------
    state : ManipulationState
        A state of the scenario.

    Returns
    -------
    numpy.ndarray, shape (2,)
    """
    return self._points(state)[0]


def boundary_points(self, state) -> np.ndarray:
    """Current positions of the sensed boundary points (``z`` without noise).

    Parameters
    ----------
    state : ManipulationState
        A state of the scenario.

    Returns
    -------
    numpy.ndarray, shape (n_boundary, 2)
    """
    return self._points(state)[self._data(state).boundary_slice]


def manipulator_positions(self, state) -> np.ndarray:
    """Current positions of the manipulators' contact points.

    Parameters
    ----------
    state : ManipulationState
        A state of the scenario.

    Returns
    -------
    numpy.ndarray, shape (m, 2)
        One row per manipulator (3 by default).
    """
    return self._points(state)[self._data(state).manipulator_slice]


def outline(self, state) -> np.ndarray:
    """The deformed boundary polygon: every boundary node at ``X + u``, counter-clockwise.

    Parameters
    ----------
    state : ManipulationState
        A state of the scenario.

    Returns
    -------
    numpy.ndarray, shape (B, 2)
    """
    d = self._data(state)
    return d.mesh.nodes[d.loop] + state.displacement[d.loop]


def obstacles(self, state=None) -> list[np.ndarray]:
    """The static obstacle (it does not move with the object).

    Parameters
    ----------
    state : ManipulationState, optional
        Unused (the obstacle is static); taken for the simulator protocol.

    Returns
    -------
    list of numpy.ndarray
        One polygon ``(k, 2)``, ``config.obstacle``.
    """
    return [self.config.obstacle]


def goal(self, state=None) -> np.ndarray:
    """The static goal polygon, the goal disk's 24-gon.

    Parameters
    ----------
    state : ManipulationState, optional
        Unused (the goal is static); taken for the simulator protocol.

    Returns
    -------
    numpy.ndarray, shape (24, 2)
    """
    return self.config.goal_polygon


def collision_outline(self, state):
    r"""The body LQG-MP checks against the obstacle (:func:`riskplan.control.lqgmp.body_points`):
    ``(outline (B, 2), a (B,), b (B,), lam (B,))``, the deformed boundary nodes of
    ``state`` (a closed polygon), each moving with the deviations of the sensed points
    ``a`` and ``b`` around it, interpolated by arc length. The 12 sensed points alone are
    ~0.28 apart, wider than the obstacle (0.14): an outline wrapped round the obstacle
    would pass between them unseen. A node's deviation is

    .. math::

        \delta p = (1 - \lambda)\, \delta p_a + \lambda\, \delta p_b

    Parameters
    ----------
    state : ManipulationState
        A state of the scenario.

    Returns
    -------
    tuple
        ``outline (B, 2)`` (:meth:`outline`), ``a (B,)`` and ``b (B,)`` int indices of the
        sensed points, ``lam (B,)`` weights in ``[0, 1]``.
    """
    a, b, lam = self._data(state).outline_weights
    return self.outline(state), a, b, lam


def in_collision(self, state) -> bool:
    """Whether the deformed object touches the obstacle (boundary edges crossing the
    obstacle's, or one polygon inside the other).

    Parameters
    ----------
    state : ManipulationState
        A state of the scenario.

    Returns
    -------
    bool
    """
    return geo.polygons_intersect(self.outline(state), self.config.obstacle)


def in_goal(self, state) -> bool:
    """Whether the target lies in the goal disk (boundary included).

    Parameters
    ----------
    state : ManipulationState
        A state of the scenario.

    Returns
    -------
    bool
    """
    return self.goal_distance(state) <= self.config.goal_radius


def goal_distance(self, state) -> float:
    """Distance from the target to the goal centre.

    Parameters
    ----------
    state : ManipulationState
        A state of the scenario.

    Returns
    -------
    float
        In scene units.
    """
    return float(np.linalg.norm(self.target(state) - np.asarray(self.config.goal_center)))


def path(self, states) -> np.ndarray:
    """Target positions along a list of states.

    Parameters
    ----------
    states : sequence of ManipulationState
        ``T`` states.

    Returns
    -------
    numpy.ndarray, shape (T, 2)
    """
    return np.array([self.target(s) for s in states])
