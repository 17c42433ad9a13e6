"""One iteration of the simulator RRT (deformable-planning paper, Patil, van den Berg &
Alterovitz, RSS 2011, section IV-A; the method and its choices are in the docstring of
:mod:`riskplan.tissue_planning.rrt`, whose :func:`~riskplan.tissue_planning.rrt.grow_tree`
runs the iterations).

The tree (``_Tree``) stores, per node, the reduced state, the full simulator state it
reached, the control and the states of the edge that reached it. An iteration
(``_Growth.iterate``), in the steps of the paper:

1. sample ``x_sample`` (the goal point with probability ``goal_bias``);
2. the nearest node by the space's metric (goal nodes are leaves; towards the goal, a
   lineage that failed ``_MAX_GOAL_FAILS`` times is no longer picked);
3. candidate controls (random in the sampling bounds or within the rate limit of the node's
   control; towards the goal, the steering rule's control replaces the last), each simulated
   for ``steps_per_extension`` steps from the node's stored state, ranked by the distance of
   their end state to the sample (an edge through the goal first); a node's steered control
   makes at most one child (the rule is deterministic: a second steered child would repeat
   the first, state for state, and so would the plans through it);
4. the best candidate whose every state is inside the space and collision-free becomes an
   edge; it ends at its first state in the (tightened) goal, which makes a goal node;
5. towards the goal, optionally, steered edges "until blocked"
   (:mod:`riskplan.tissue_planning.rrt_connect`).
"""

from __future__ import annotations

import logging

import numpy as np

from riskplan._validation import as_array
from riskplan.tissue_planning.rrt_connect import _SIM_FAILURES, _connect_edge, _in_goal

log = logging.getLogger("riskplan.tissue_planning.rrt")

__all__: list[str] = []

#: Goal-directed extensions of a node's lineage after which it is no longer picked for the
#: goal (a car facing away from the goal would otherwise be picked again and again).
_MAX_GOAL_FAILS = 3


class _Tree:
    """A growing tree: reduced states ``X`` (doubled when full), full states, edges, goals."""

    def __init__(self, root, x0, u0, q: int, cap: int = 1024):
        self.X = np.empty((cap, x0.shape[0]))
        self.X[0] = x0
        self.is_goal = np.zeros(cap, dtype=bool)
        self.goal_fails = np.zeros(cap, dtype=np.int64)
        self.parents, self.node_control = [-1], [u0]
        self.node_state = [root]  # full state y of every node; edge_states: after each step
        self.edge_states: list[tuple] = [()]
        self.edge_controls: list[np.ndarray] = [np.empty((0, q))]
        self.has_goal_child = [False]
        # whether the node's steered control already made a child: the steering rule is
        # deterministic (the same control from a node towards the goal point each time), so
        # a second steered child would repeat the first, state for state
        self.steered = [False]
        self.goal_nodes: list[int] = []
        self.n = 1

    def add(self, sim, parent: int, seq, u, at_goal: bool) -> None:
        n = self.n  # the node reached by the edge ``seq`` (states) under control ``u``
        if n == self.X.shape[0]:
            self.X = np.concatenate([self.X, np.empty_like(self.X)])
            self.is_goal = np.concatenate([self.is_goal, np.zeros_like(self.is_goal)])
            self.goal_fails = np.concatenate([self.goal_fails, np.zeros_like(self.goal_fails)])
        self.X[n] = np.asarray(sim.reduced(seq[-1]), dtype=np.float64)
        self.parents.append(parent)
        self.node_state.append(seq[-1])
        self.edge_states.append(tuple(seq))
        self.edge_controls.append(np.tile(u, (len(seq), 1)))
        self.node_control.append(u)
        self.has_goal_child.append(False)
        self.steered.append(False)
        if at_goal:
            self.has_goal_child[parent] = True
            self.is_goal[n] = True
            self.goal_nodes.append(n)
        self.n = n + 1


def _check_edge(sim, space, seq, end, r_tight: float) -> tuple[bool, int | None]:
    """``(valid, goal_at)`` of the candidate edge ``seq`` (its states; ``end`` the reduced
    last one): valid if every state up to its first in the tightened goal (``goal_at``, or
    ``None``) is finite, inside the space and collision-free (paper IV-A, steps 4-5)."""
    for j, st in enumerate(seq):
        xj = end if j == len(seq) - 1 else np.asarray(sim.reduced(st), dtype=np.float64)
        if not (np.all(np.isfinite(xj)) and space.contains(xj)) or sim.in_collision(st):
            return False, None
        if _in_goal(sim, st, r_tight):
            return True, j
    return True, None


class _Growth:
    """The state of one growing tree: the simulator, its planning parameters and space, the
    options (``RRTOptions``), the control bounds, the tightened goal radius, the random
    stream, the tree and the simulator steps taken (``n_steps``)."""

    def __init__(self, sim, params, space, options, bounds, r_tight, gen, tree: _Tree):
        self.sim, self.params, self.space, self.options = sim, params, space, options
        self.bounds, self.r_tight, self.gen, self.tree = bounds, r_tight, gen, tree
        self.steer = space.steer if options.goal_steer else None
        self.n_steps = 0

    def iterate(self) -> None:
        """One iteration (module docstring, steps 1-5)."""
        tree, space = self.tree, self.space
        x_s, to_goal = space.sample(self.gen, self.options.goal_bias)
        n = tree.n
        dn = space.distance(tree.X[:n], x_s, to_goal=to_goal)
        dn[tree.is_goal[:n]] = np.inf  # goal nodes are leaves
        if to_goal:
            dn[tree.goal_fails[:n] >= _MAX_GOAL_FAILS] = np.inf
            if not np.isfinite(dn).any():
                return
        near = int(np.argmin(dn))
        U, steered = self._candidate_controls(near, x_s, to_goal)
        ends, traj = self._simulate(near, U)
        ok, dist = self._rank(ends, traj, x_s, to_goal)
        added = self._add_best(near, U, ends, traj, ok, dist, dn[near], to_goal, steered)
        first_new = tree.n - 1
        if to_goal and added and self.steer is not None and not tree.is_goal[tree.n - 1]:
            self._connect(x_s)
        if to_goal:
            # every goal-directed attempt counts, and a child made by one inherits the count:
            # a lineage creeping towards the goal with tiny steps (or facing away from it)
            # stops being picked for the goal after _MAX_GOAL_FAILS attempts
            tree.goal_fails[near] += 1
            if added:  # the edge's node and those of its goal connection
                tree.goal_fails[first_new : tree.n] = tree.goal_fails[near]

    def _candidate_controls(self, near: int, x_s, to_goal: bool) -> tuple[np.ndarray, bool]:
        """``(U, steered)``: ``(n_controls, q)`` controls to try from node ``near`` (step 3),
        and whether the last is the steering rule's."""
        bounds, space, gen = self.bounds, self.space, self.gen
        n_ctrl, q = self.options.n_controls, bounds.shape[0]
        u_near = self.tree.node_control[near]
        if space.max_control_change is None:
            U = bounds[:, 0] + gen.random((n_ctrl, q)) * (bounds[:, 1] - bounds[:, 0])
        else:
            d = space.max_control_change
            U = u_near + (2.0 * gen.random((n_ctrl, q)) - 1.0) * d
            U = np.clip(U, bounds[:, 0], bounds[:, 1])
        steered = False
        if to_goal and self.steer is not None and not self.tree.steered[near]:
            # the space's local steering towards the goal point is one of the candidates
            # (drawn after the random ones, so the random stream does not depend on it);
            # once it made a child of this node, the random candidates alone are tried
            u_st = self.steer(self.tree.X[near].copy(), x_s, bounds, space.steps_per_extension)
            if u_st is not None:
                u_st = as_array(u_st, "space.steer(...)", shape=(q,))
                if space.max_control_change is not None:  # the space's rate limit holds too
                    d = space.max_control_change
                    u_st = np.clip(u_st, u_near - d, u_near + d)
                U[-1] = np.clip(u_st, bounds[:, 0], bounds[:, 1])
                steered = True
        return U, steered

    def _simulate(self, near: int, U: np.ndarray):
        """Each candidate simulated for ``steps_per_extension`` steps from the node's state:
        ``ends (n_controls, p)`` the reduced end states (NaN where the solve failed or the
        state is not finite) and ``traj`` the states of each edge (``None`` there)."""
        sim, k_steps = self.sim, self.space.steps_per_extension
        ends = np.full((len(U), self.space.dim), np.nan)
        traj: list = [None] * len(U)
        for c in range(len(U)):
            st = self.tree.node_state[near]
            seq = []
            try:
                for _ in range(k_steps):
                    st = sim.step(st, U[c], self.params)
                    seq.append(st)
            except _SIM_FAILURES as exc:
                log.debug("rrt: candidate control discarded (%s)", exc)
                self.n_steps += len(seq) + 1
                continue
            self.n_steps += k_steps
            xe = np.asarray(sim.reduced(st), dtype=np.float64)
            if np.all(np.isfinite(xe)):
                ends[c] = xe
                traj[c] = seq
        return ends, traj

    def _rank(self, ends, traj, x_s, to_goal: bool):
        """``(ok, dist)``: which candidates ran, and their distances to the sample (``inf``
        for the failed ones; ``-1`` for an edge through the goal, with ``goal_entry``)."""
        ok = np.isfinite(ends[:, 0])
        dist = self.space.distance(np.where(ok[:, None], ends, 0.0), x_s, to_goal=to_goal)
        dist[~ok] = np.inf
        if to_goal and self.options.goal_entry:
            # an edge through the goal ends there: it ranks first (stable among such edges)
            for c in np.flatnonzero(ok):
                if any(_in_goal(self.sim, st, self.r_tight) for st in traj[c]):
                    dist[c] = -1.0
        return ok, dist

    def _add_best(
        self, near: int, U, ends, traj, ok, dist, d_near, to_goal: bool, steered: bool
    ) -> bool:
        """Add the best valid candidate as an edge from ``near`` (steps 4-5); whether one
        was added. ``steered``: the last candidate is the steering rule's."""
        tree = self.tree
        for c in np.argsort(dist, kind="stable"):
            if not ok[c] or (to_goal and dist[c] >= d_near):
                break  # towards the goal, only an edge that gets closer is worth adding
            seq = traj[c]
            accepted, goal_at = _check_edge(self.sim, self.space, seq, ends[c], self.r_tight)
            if not accepted:
                continue
            if goal_at is not None:
                if tree.has_goal_child[near]:
                    break  # one goal child per node keeps the plans of a tree distinct
                seq = seq[: goal_at + 1]
            tree.add(self.sim, near, seq, U[c], goal_at is not None)
            if steered and c == len(U) - 1:
                tree.steered[near] = True
            return True
        return False

    def _connect(self, x_s) -> None:
        """Up to ``goal_connect`` steered edges from the newest node towards the goal point,
        until one is blocked or reaches the goal (:mod:`riskplan.tissue_planning.rrt_connect`)."""
        tree = self.tree
        k_steps = self.space.steps_per_extension
        ctx = (self.sim, self.params, self.space, self.steer, self.bounds, k_steps, self.r_tight)
        for _ in range(self.options.goal_connect):
            node = tree.n - 1
            seq, u_c, taken, at_goal = _connect_edge(
                *ctx, tree.node_state[node], tree.X[node], tree.node_control[node], x_s
            )
            self.n_steps += taken
            if seq is None:
                break
            tree.add(self.sim, node, seq, u_c, at_goal)
            tree.steered[node] = True  # its steered control: the one just taken
            if at_goal:
                break
