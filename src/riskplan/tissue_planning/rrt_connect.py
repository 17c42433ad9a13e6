"""Pieces of the simulator RRT (:mod:`riskplan.tissue_planning.rrt`): the goal tests of an
edge and the goal connection of :class:`~riskplan.tissue_planning.rrt.RRTOptions`
``goal_connect``.

**Goal connection** (default off): after a goal-directed extension added a node (not a
goal node), the tree keeps extending from the newest node with the steering rule's control
alone (``PlanningSpace.steer``; no random candidates) for up to ``goal_connect`` more
edges, until one ends in the goal, is blocked (leaves the space or touches an obstacle) or
gets no closer to the goal point: the "extend until blocked" of RRT-Connect (Kuffner &
LaValle, ICRA 2000) towards the goal. Each edge is checked as any other (every state in
the space and collision-free, the goal entry); the connection draws no random numbers and
counts as the one goal-directed attempt that started it. Without it a lineage reaches the
goal by at most ``_MAX_GOAL_FAILS`` goal-directed extensions, so a goal farther than that
many edges from every node is reached only by chance; the 3-D needle, 0.8 from its target
in edges of at most 0.3, plans with it.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from riskplan._validation import as_array
from riskplan.errors import (
    ConvergenceError,
    ElementInversionError,
    InvalidInputError,
    SimulationError,
)

log = logging.getLogger(__name__)

#: Errors a simulator may raise for one candidate control; such a candidate is discarded.
_SIM_FAILURES = (ConvergenceError, ElementInversionError, SimulationError, FloatingPointError)


def _goal_radius(sim, options) -> float:
    """``(1 − goal_depth) · sim.goal_radius``, or ``inf`` when ``goal_depth`` is 0."""
    if options.goal_depth == 0.0:
        return math.inf
    r = getattr(sim, "goal_radius", None)
    if r is None:
        raise InvalidInputError(
            f"options.goal_depth: {type(sim).__name__} has no goal_radius; use goal_depth=0"
        )
    return (1.0 - options.goal_depth) * float(r)


def _in_goal(sim, st, r_tight: float) -> bool:
    """Whether ``st`` ends an edge: in ``sim``'s goal and within ``r_tight`` of its centre
    (the cheaper distance test first)."""
    if r_tight == math.inf:
        return bool(sim.in_goal(st))
    return bool(sim.goal_distance(st) <= r_tight and sim.in_goal(st))


def _connect_edge(sim, params, space, steer, bounds, k_steps, r_tight, y, x, u_node, x_goal):
    """One edge of the goal connection (:class:`RRTOptions` ``goal_connect``) from the node
    with full state ``y`` and reduced state ``x``: the steering rule's control held for
    ``k_steps``. Returns ``(states, control, steps, ends_in_goal)``: the states cut at the
    goal entry, and the simulator steps taken; ``states`` is ``None`` when the steering
    rule or the simulator gives up, or the edge is blocked or gets no closer to
    ``x_goal``."""
    u = steer(x.copy(), x_goal, bounds, k_steps)
    if u is None:
        return None, None, 0, False
    u = as_array(u, "space.steer(...)", shape=(bounds.shape[0],))
    if space.max_control_change is not None:
        d = space.max_control_change
        u = np.clip(u, u_node - d, u_node + d)
    u = np.clip(u, bounds[:, 0], bounds[:, 1])
    d0 = float(space.distance(x[None, :], x_goal, to_goal=True)[0])
    seq, st = [], y
    try:
        for _ in range(k_steps):
            st = sim.step(st, u, params)
            seq.append(st)
    except _SIM_FAILURES as exc:
        log.debug("rrt: goal connection stopped (%s)", exc)
        return None, None, len(seq) + 1, False
    for j, st in enumerate(seq):
        xj = np.asarray(sim.reduced(st), dtype=np.float64)
        if not (np.all(np.isfinite(xj)) and space.contains(xj)) or sim.in_collision(st):
            return None, None, k_steps, False
        if _in_goal(sim, st, r_tight):
            return seq[: j + 1], u, k_steps, True
    xe = np.asarray(sim.reduced(seq[-1]), dtype=np.float64)
    if not float(space.distance(xe[None, :], x_goal, to_goal=True)[0]) < d0:
        return None, None, k_steps, False
    return seq, u, k_steps, False
