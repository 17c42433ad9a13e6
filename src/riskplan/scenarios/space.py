"""The planning seam: what a scenario hands the simulator RRT (Patil, van den Berg &
Alterovitz, RSS 2011, section IV-A).

The planner (:mod:`riskplan.tissue_planning.rrt`) knows no scenario by type. A scenario that can
be planned for is a :class:`PlanningScenario`: a
:class:`~riskplan.scenarios.base.Simulator` that also tests collisions and the goal on its
full states and hands over a :class:`PlanningSpace` from ``planning_space()``. The space
says where the tree samples, how it measures, which reduced states are valid and how an
edge is extended:

.. math::

    d(x, x')^2 = \\sum_i w_i \\, \\delta_i^2, \\qquad
    \\delta_i = x_i - x'_i \\ \\text{(wrapped to } (-\\pi, \\pi] \\text{ if periodic)}.

:class:`BoxSpace` is the implementation both paper scenarios use (a box, a weighted
metric with periodic components, a goal point, an optional steering rule); a scenario
whose reduced state is not a box (orientations, a graph of lanes) implements the
protocol's three methods itself. The two paper scenarios build theirs in
:meth:`riskplan.scenarios.needle.NeedleScenario.planning_space` and
:meth:`riskplan.scenarios.manipulation.ManipulationScenario.planning_space`; the tests
plan, execute and run LQG-MP for a scenario written outside the package.

Control bounds and their margins come from the simulator: ``control_bounds (q, 2)`` and,
optionally, ``actuation_cov() (q, q)``, whose standard deviations narrow the bounds the
RRT samples in (:func:`riskplan.tissue_planning.rrt.sampling_bounds`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from riskplan._validation import as_array, check_count
from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import Simulator

__all__ = ["BoxSpace", "PlanningScenario", "PlanningSpace"]


@runtime_checkable
class PlanningSpace(Protocol):
    """Where and how the simulator RRT samples, measures and extends (paper IV-A).

    Attributes
    ----------
    dim : int
        ``p``, the dimension of the reduced state ``x``.
    goal : numpy.ndarray
        ``(p,)`` the point the goal bias samples.
    steps_per_extension : int
        Simulator steps one edge holds its control for.
    max_control_change : numpy.ndarray or None
        ``None`` (controls uniform in the bounds) or ``(q,)``: a child's control lies within
        this of its parent's (the root's control is the midpoint of the bounds).
    steer : callable or None
        ``None`` or a local steering rule ``steer(x_from (p,), x_to (p,), bounds (q, 2),
        steps) -> (q,)`` (or ``None``): a control that, held for at most ``steps`` steps,
        drives the reduced state from ``x_from`` towards ``x_to`` within ``bounds``.
    """

    dim: int
    goal: np.ndarray
    steps_per_extension: int
    max_control_change: np.ndarray | None
    steer: Callable | None

    def sample(self, gen: np.random.Generator, goal_bias: float = 0.0) -> tuple[np.ndarray, bool]:
        """Draw a sample of the reduced state.

        Parameters
        ----------
        gen : numpy.random.Generator
            The tree's random stream.
        goal_bias : float
            Probability of returning the goal point.

        Returns
        -------
        x : numpy.ndarray
            ``(p,)`` the sample.
        is_goal : bool
            Whether it is the goal point.
        """
        ...

    def distance(self, xs: np.ndarray, x: np.ndarray, *, to_goal: bool = False) -> np.ndarray:
        """Distances of the metric.

        Parameters
        ----------
        xs : numpy.ndarray
            ``(n, p)`` reduced states (the tree's nodes, or candidate end states).
        x : numpy.ndarray
            ``(p,)`` the sample.
        to_goal : bool
            ``x`` is the goal point: measure only what the goal constrains.

        Returns
        -------
        numpy.ndarray
            ``(n,)`` non-negative distances.
        """
        ...

    def contains(self, x: np.ndarray) -> bool:
        """Whether a reduced state is valid (inside the space).

        Parameters
        ----------
        x : numpy.ndarray
            ``(p,)`` reduced state.

        Returns
        -------
        bool
            ``False`` makes the edge reaching ``x`` invalid.
        """
        ...


@runtime_checkable
class PlanningScenario(Simulator, Protocol):
    """A :class:`~riskplan.scenarios.base.Simulator` the simulator RRT can plan for.

    Attributes
    ----------
    goal_radius : float
        Radius of the goal region (``RRTOptions.goal_depth`` tightens it).

    Notes
    -----
    Optional: ``actuation_cov() -> (q, q)``, the actuation noise covariance whose standard
    deviations narrow the control bounds the RRT samples in
    (``RRTOptions.control_margin``); without it the full bounds are used.
    """

    goal_radius: float

    def planning_space(self) -> PlanningSpace:
        """The space the RRT grows in.

        Returns
        -------
        PlanningSpace
            Sampling, metric, validity and extension rule of this scenario.
        """
        ...

    def in_collision(self, state) -> bool:
        """Whether the full state collides with the (deformed) obstacles.

        Parameters
        ----------
        state : SimState

        Returns
        -------
        bool
        """
        ...

    def in_goal(self, state) -> bool:
        """Whether the goal point of ``state`` lies in the (deformed) goal region.

        Parameters
        ----------
        state : SimState

        Returns
        -------
        bool
        """
        ...

    def goal_distance(self, state) -> float:
        """Distance from the goal point of ``state`` to the (deformed) goal centre.

        Parameters
        ----------
        state : SimState

        Returns
        -------
        float
        """
        ...


@dataclass(frozen=True, eq=False)
class BoxSpace:
    """A :class:`PlanningSpace` over a box with a weighted metric (both paper scenarios).

    .. math::

        d(x, x')^2 = \\sum_i w_i \\, \\delta_i^2, \\qquad
        \\delta_i = x_i - x'_i \\ \\text{(wrapped to } (-\\pi, \\pi] \\text{ if periodic)}

    Towards the goal point the periodic components are ignored (a goal region is a region
    of positions; any heading will do).

    Parameters
    ----------
    low, high : array_like
        ``(p,)`` sampling box of the reduced state ``x``; states whose weighted,
        non-periodic components leave it are invalid.
    weights : array_like
        ``(p,)`` non-negative weights ``w`` of the metric (0: component ignored, not
        sampled and not bounded).
    periodic : array_like
        ``(p,)`` bool, angles wrapped to ``(−π, π]`` in the metric.
    goal : array_like
        ``(p,)`` the point the goal bias samples.
    steps_per_extension : int
        Simulator steps one edge holds its control for.
    max_control_change : array_like or None
        ``None`` or ``(q,)``, see :class:`PlanningSpace`.
    steer : callable or None
        ``None`` or a local steering rule, see :class:`PlanningSpace`. Needle:
        :func:`riskplan.scenarios.needle.car_steer`.
    """

    low: np.ndarray
    high: np.ndarray
    weights: np.ndarray
    periodic: np.ndarray
    goal: np.ndarray
    steps_per_extension: int = 1
    max_control_change: np.ndarray | None = None
    steer: Callable | None = None

    def __post_init__(self):
        low = as_array(self.low, "low", shape=(None,))
        p = low.shape[0]
        high = as_array(self.high, "high", shape=(p,))
        w = as_array(self.weights, "weights", shape=(p,))
        per = np.asarray(self.periodic, dtype=bool)
        if per.shape != (p,):
            raise InvalidInputError(f"periodic: expected shape ({p},), got {per.shape}")
        goal = as_array(self.goal, "goal", shape=(p,))
        if np.any(w < 0) or not np.any(w > 0):
            raise InvalidInputError("weights: expected non-negative values, at least one > 0")
        if np.any(high[w > 0] <= low[w > 0]):
            raise InvalidInputError("high: must exceed low on every weighted component")
        k = check_count(self.steps_per_extension, "steps_per_extension", 1)
        object.__setattr__(self, "steps_per_extension", k)
        for name, v in (
            ("low", low),
            ("high", high),
            ("weights", w),
            ("periodic", per),
            ("goal", goal),
        ):
            v = np.array(v)
            v.setflags(write=False)
            object.__setattr__(self, name, v)
        if self.steer is not None and not callable(self.steer):
            raise InvalidInputError(
                f"steer: expected None or a callable, got {type(self.steer).__name__}"
            )
        if self.max_control_change is not None:
            d = as_array(self.max_control_change, "max_control_change", shape=(None,))
            if np.any(d <= 0):
                raise InvalidInputError("max_control_change: expected values > 0")
            d = np.array(d)
            d.setflags(write=False)
            object.__setattr__(self, "max_control_change", d)
        # precomputed for the hot loop
        object.__setattr__(self, "_sqrt_w", np.sqrt(w))
        object.__setattr__(self, "_sqrt_w_goal", np.where(per, 0.0, np.sqrt(w)))
        object.__setattr__(self, "_bounded", (w > 0) & ~per)

    @property
    def dim(self) -> int:
        """``p``, the dimension of the reduced state."""
        return int(self.low.shape[0])

    def sample(self, gen: np.random.Generator, goal_bias: float = 0.0) -> tuple[np.ndarray, bool]:
        """The goal point with probability ``goal_bias``, else uniform in the box.

        ``p + 1`` uniforms of ``gen`` per call (:meth:`PlanningSpace.sample`).

        Parameters
        ----------
        gen : numpy.random.Generator
        goal_bias : float
            In [0, 1].

        Returns
        -------
        tuple
            ``(point (p,), is_goal)``.
        """
        u = gen.random(self.dim + 1)
        if u[-1] < goal_bias:
            return self.goal.copy(), True
        return self.low + u[:-1] * (self.high - self.low), False

    def scaled(self, x: np.ndarray) -> np.ndarray:
        """Coordinates in which the metric is Euclidean.

        Parameters
        ----------
        x : numpy.ndarray
            ``(..., p)`` reduced states.

        Returns
        -------
        numpy.ndarray
            ``(..., p)`` ``sqrt(w) · x`` (periodic components wrapped only by
            :meth:`distance`).
        """
        return x * self._sqrt_w

    def distance(self, xs: np.ndarray, x: np.ndarray, *, to_goal: bool = False) -> np.ndarray:
        """Weighted distance from each row of ``xs`` to ``x``.

        Parameters
        ----------
        xs : numpy.ndarray
            ``(n, p)`` reduced states (not modified).
        x : numpy.ndarray
            ``(p,)`` the sample.
        to_goal : bool
            The distance to the goal point, which ignores the periodic components.

        Returns
        -------
        numpy.ndarray
            ``(n,)`` distances.
        """
        d = xs - x
        if to_goal:
            d *= self._sqrt_w_goal
        else:
            if self.periodic.any():
                d[:, self.periodic] = (d[:, self.periodic] + math.pi) % (2.0 * math.pi) - math.pi
            d *= self._sqrt_w
        return np.sqrt(np.einsum("ij,ij->i", d, d))

    def contains(self, x: np.ndarray) -> bool:
        """Whether the weighted, non-periodic components of ``x`` lie in the box
        (:meth:`PlanningSpace.contains`).

        Parameters
        ----------
        x : numpy.ndarray, (p,)

        Returns
        -------
        bool
        """
        b = self._bounded
        return bool(np.all(x[b] >= self.low[b]) and np.all(x[b] <= self.high[b]))
