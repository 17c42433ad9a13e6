"""Simulator-based RRT for deformable environments (Patil, van den Berg & Alterovitz,
RSS 2011, section IV-A; RRT after LaValle & Kuffner).

The tree grows over the reduced state ``x`` (paper section III) while every node also
stores the full simulator state ``y`` (FEM displacement, robot pose, applied loads), so
expanding a node restarts the simulation from exactly the deformation it reached. Plans
assume the expected deformation: the tree is grown with the planning parameters
``sim.nominal_params`` (no actuation noise).

One iteration (paper IV-A):

1. draw ``x_sample``: uniform in the sampling box of the
   :class:`~riskplan.scenarios.space.PlanningSpace`, or,
   with probability ``goal_bias``, the goal point (towards which distances ignore the
   periodic components: any heading will do in a goal region of positions);
2. nearest node by the weighted metric of the space (vectorised over all nodes)

       d(x, x')² = Σ_i w_i δ_i²,   δ_i = x_i − x'_i  (wrapped to (−π, π] if periodic);

3. draw ``n_controls`` controls (uniform in the control bounds narrowed by
   ``control_margin`` actuation standard deviations, or within
   ``max_control_change`` of the node's own control), simulate each for
   ``steps_per_extension`` steps from the node's stored state and rank them by the
   distance of their end state to ``x_sample``. Towards the goal point, if the space has
   a local steering rule (``PlanningSpace.steer``; the needle's lands the car exactly on
   the goal point when its bounds allow), its control replaces the last random candidate
   (``goal_steer``), and a candidate with a state in the (tightened) goal ranks first,
   since its edge ends there (``goal_entry``; see :class:`RRTOptions`);
4. take the best candidate whose every intermediate state lies inside the space's box and
   is collision-free against the *deformed* obstacles (``sim.in_collision``); candidates
   are checked lazily in rank order, so collision checks are paid only until one passes;
5. if an intermediate state lies in the *deformed* goal region (``sim.in_goal``), and
   within ``(1 − goal_depth) · r_goal`` of its centre (``sim.goal_distance``; see
   :class:`RRTOptions`), the edge ends there and the new node is a goal node: a leaf, never
   expanded. At most one goal
   child per node, and at most one child made by a node's steered control (the steering
   rule is deterministic: asked again from the same node, it would add a copy of that
   child, state for state, and the plans through it would repeat), so the plans of one
   tree are distinct.

A plan is the path from the root to a goal node: the controls of its edges (each held
for its steps) and every state on the way, as a :class:`riskplan.control.NominalPlan`.
Many distinct candidates (the paper uses 100) come from several trees with independent
seeds, each collecting ``plans_per_tree`` goal nodes; the trees run through
:mod:`riskplan.parallel`, and a tree's result depends only on its seed, so the plans do
not depend on the backend or on the number of workers. The trees share the root, and a
path of steered edges from it is the same in every tree that takes it: a plan repeating
an earlier tree's is kept once.

Choices the paper leaves open (documented in docs/planning.md):

* steps per extension: the paper does not say. Needle: 3 steps of τ = 0.1 (at most
  0.15 length units, about the goal disk's diameter); manipulation: 1
  step of force increments uniform in their bounds (``±df_max = ±0.25 f_max``, narrowed
  by the control margin): the increment bound is the rate limit, because a quasi-static
  step jumps to the equilibrium of the new forces and larger force jumps would skip the
  intermediate configurations that the collision check and the linearisation never see.
* metric: needle ``(x, y)`` plus ``r_min · θ`` (a heading error of 1 rad counts like the
  arc the car needs to turn by it; with 0.1 instead, trees more often crept past the goal
  with the wrong heading and took 3–10 times as many iterations); manipulation: the target
  position only (the boundary points follow it).
* states outside the sampling box are invalid (the needle leaving the tissue).

The planner knows no scenario by type: it plans for any
:class:`~riskplan.scenarios.space.PlanningScenario` (a
:class:`~riskplan.scenarios.base.Simulator` with ``in_collision(state)``,
``in_goal(state)``, ``goal_distance(state)``, ``goal_radius`` and ``planning_space()``), or
for a simulator with the first four given a space (argument ``space``). The two paper
scenarios build theirs in ``NeedleScenario.planning_space`` and
``ManipulationScenario.planning_space``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_generator, check_count
from riskplan.errors import (
    InvalidInputError,
    PlanningError,
)
from riskplan.scenarios.space import PlanningSpace
from riskplan.tissue_planning.rrt_connect import _goal_radius
from riskplan.tissue_planning.rrt_extend import _Growth, _Tree

log = logging.getLogger(__name__)

__all__ = [
    "RRTOptions",
    "TreeResult",
    "actuation_std",
    "grow_tree",
    "planning_space",
    "rrt_plans",
    "sampling_bounds",
]


def planning_space(sim) -> PlanningSpace:
    """The space ``sim`` hands over for planning.

    Parameters
    ----------
    sim : PlanningScenario
        A simulator with a ``planning_space()`` method
        (:class:`riskplan.scenarios.space.PlanningScenario`).

    Returns
    -------
    PlanningSpace
        ``sim.planning_space()``, checked against the protocol.
    """
    method = getattr(sim, "planning_space", None)
    if not callable(method):
        raise InvalidInputError(
            f"sim: {type(sim).__name__} has no planning_space() method "
            "(riskplan.scenarios.space.PlanningScenario); pass space=BoxSpace(...) instead"
        )
    space = method()
    if not isinstance(space, PlanningSpace):
        raise InvalidInputError(
            f"sim.planning_space(): expected a PlanningSpace, got {type(space).__name__}"
        )
    return space


@dataclass(frozen=True)
class RRTOptions:
    """Budget and sampling of one tree.

    ``n_controls``: controls sampled per extension (the best valid one is kept);
    ``goal_bias``: probability of sampling the goal point; ``max_iterations``: iterations
    per tree (each one extension attempt); ``plans_per_tree``: goal nodes a tree collects
    before it stops.

    ``goal_depth`` (in ``[0, 1)``): a goal node must lie in the goal *and* within
    ``(1 − goal_depth) · r_goal`` of the (deformed) goal centre, ``sim.goal_distance``
    (``r_goal``: ``sim.goal_radius`` or ``sim.config.goal_radius``). Planning to a
    tightened goal leaves the feedback controller room: a plan ending on the goal's edge
    misses the goal under any execution error. 0: the first state in the goal ends a plan.

    ``control_margin``: controls are sampled in ``[low + m, high − m]`` with
    ``m = control_margin · σ`` per control, ``σ`` the standard deviation of the scenario's
    actuation noise (:func:`actuation_std`). A nominal control on a bound has its noise
    clipped on one side (a biased execution) and leaves the feedback no authority in that
    direction; 2σ keeps about 98 % of each one-sided noise draw inside the bounds.
    0: the whole bounds.

    ``goal_entry``: in a goal-directed extension (the goal point sampled), a candidate
    edge with a state in the (tightened) goal ranks before the others (it ends there, so
    its end *is* in the goal), the others by the distance of their end state as usual.
    Without it a candidate that passes through the goal and comes out on the far side
    ranks by that far end, and is dropped when the far end is no closer than the node
    (for 100 needle plans, the goal entry alone cut the trees needed from 15 to 13;
    docs/planning.md). False: every candidate ranked by its end state.

    ``goal_steer``: in a goal-directed extension, the control of the space's steering rule
    (``PlanningSpace.steer``, if it has one) towards the goal point replaces the last of
    the ``n_controls`` random candidates (the others stay random, so the tree still
    explores; the random draws are the same with or without it). The kinodynamic RRT
    extends a node with the input that brings it closest to the sample (LaValle &
    Kuffner, IJRR 2001); a steering rule proposes such an input directly instead of
    hoping that a random one comes close. It is used for the goal point only. With the
    needle's tightened goal, random candidates rarely landed a state within half the goal
    radius, and 7 of the 15 trees for 100 plans ran to ``max_iterations`` (with the
    steering: 1 of 11; docs/planning.md). ``goal_entry = goal_steer = False,
    goal_depth = control_margin = 0``: the plans of the original tree, bit for bit.

    ``goal_connect`` (default 0: off): up to that many steered edges after a goal-directed
    one, "extend until blocked" (:mod:`riskplan.tissue_planning.rrt_connect`).
    """

    n_controls: int = 4
    goal_bias: float = 0.3
    max_iterations: int = 2000
    plans_per_tree: int = 10
    goal_depth: float = 0.5
    control_margin: float = 2.0
    goal_entry: bool = True
    goal_steer: bool = True
    goal_connect: int = 0

    def __post_init__(self):
        for name in ("n_controls", "max_iterations", "plans_per_tree"):
            check_count(getattr(self, name), name, 1)  # junk types: named, not a TypeError
        check_count(self.goal_connect, "goal_connect", 0)
        for name in ("goal_bias", "goal_depth", "control_margin"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
                raise InvalidInputError(f"{name}: expected a number, got {v!r}")
        if not 0.0 <= self.goal_bias <= 1.0:
            raise InvalidInputError(
                f"goal_bias: expected a value in [0, 1], got {self.goal_bias!r}"
            )
        if not 0.0 <= self.goal_depth < 1.0:
            raise InvalidInputError(
                f"goal_depth: expected a value in [0, 1), got {self.goal_depth!r}"
            )
        for name in ("goal_entry", "goal_steer"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InvalidInputError(
                    f"{name}: expected True or False, got {getattr(self, name)!r}"
                )
        if not (math.isfinite(self.control_margin) and self.control_margin >= 0.0):
            raise InvalidInputError(
                f"control_margin: expected a finite value >= 0, got {self.control_margin!r}"
            )


@dataclass
class TreeResult:
    """What one tree returns: its plans, its nodes (for figures) and its statistics.

    ``nodes (n, p)`` reduced states of the nodes, ``parents (n,)`` (root: −1),
    ``goal_nodes``: node indices of the plans' ends, ``best_goal_distance``: the
    simulator's goal distance of the node nearest the goal point (by the metric),
    ``n_sim_steps``: simulator steps taken, ``cpu_s``: CPU seconds of the process growing it.
    """

    seed: int
    plans: list
    nodes: np.ndarray
    parents: np.ndarray
    goal_nodes: list
    iterations: int
    best_goal_distance: float
    n_sim_steps: int = 0
    cpu_s: float = 0.0

    @property
    def size(self) -> int:
        return int(self.nodes.shape[0])


def actuation_std(sim) -> np.ndarray | None:
    """The standard deviations of ``sim``'s actuation noise.

    Parameters
    ----------
    sim : Simulator
        The scenario; its ``actuation_cov()`` if it has one: the manipulation scenario's
        ``0.1 df_max``, the needle's ``config.actuation_std`` (``(0.1 v_max, 5° · φ_max /
        60°)`` unless set: the paper's ``(0.05, 5°)``, scaled with the control bounds).

    Returns
    -------
    numpy.ndarray or None
        ``(q,)`` the square roots of the covariance's diagonal; ``None`` if unknown.
    """
    cov = getattr(sim, "actuation_cov", None)
    if callable(cov):
        return np.sqrt(np.diag(np.asarray(cov(), dtype=np.float64)))
    return None


def sampling_bounds(sim, options: RRTOptions) -> np.ndarray:
    """The bounds the RRT samples controls in (see :class:`RRTOptions`).

    Parameters
    ----------
    sim : Simulator
        The scenario (``control_bounds``, and its actuation noise, :func:`actuation_std`).
    options : RRTOptions
        Its ``control_margin``: standard deviations of the actuation noise kept clear of
        each bound.

    Returns
    -------
    numpy.ndarray
        ``(q, 2)``: ``sim.control_bounds`` narrowed by ``options.control_margin`` actuation
        standard deviations on each side; the full bounds when the margin is 0 or the noise
        unknown. Raises :class:`~riskplan.errors.InvalidInputError` when the margin leaves
        no controls.
    """
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    if options.control_margin == 0.0:
        return bounds
    std = actuation_std(sim)
    if std is None:
        log.info(
            "rrt: %s has no actuation noise model; controls use the full bounds", type(sim).__name__
        )
        return bounds
    if std.shape != (bounds.shape[0],):
        raise InvalidInputError(
            f"sim: actuation noise has {std.shape[0]} components, but {bounds.shape[0]} controls"
        )
    m = options.control_margin * std
    out = np.stack([bounds[:, 0] + m, bounds[:, 1] - m], axis=1)
    if np.any(out[:, 1] <= out[:, 0]):
        raise InvalidInputError(
            f"options.control_margin: {options.control_margin} standard deviations {std.tolist()} leave no controls "
            f"inside the bounds {bounds.tolist()}"
        )
    return out


def _check_sim(sim) -> None:
    for name in (
        "step",
        "reduced",
        "initial_state",
        "control_bounds",
        "in_collision",
        "in_goal",
        "goal_distance",
    ):
        if not hasattr(sim, name):
            raise InvalidInputError(
                f"sim: {type(sim).__name__} lacks {name!r}, which the simulator RRT needs"
            )


def grow_tree(
    sim, *, seed, params=None, space: PlanningSpace | None = None, options: RRTOptions | None = None
) -> TreeResult:
    """Grow one simulator RRT (paper IV-A) from ``sim.initial_state(params)`` until it has
    ``options.plans_per_tree`` goal nodes or ``options.max_iterations`` iterations.

    Each iteration is one extension attempt (module docstring, steps 1-5;
    :mod:`riskplan.tissue_planning.rrt_extend`). Deterministic in ``seed``.

    Parameters
    ----------
    sim : PlanningScenario
        The simulator (``step``, ``reduced``, ``initial_state``, ``control_bounds``,
        ``in_collision``, ``in_goal``, ``goal_distance``).
    seed : int or numpy.random.Generator
        Seeds the samples and the candidate controls.
    params : SimParams, optional
        The planning parameters (default ``sim.nominal_params``: the expected deformation).
    space : PlanningSpace, optional
        The space to plan in (default :func:`planning_space` of ``sim``).
    options : RRTOptions, optional
        Budget and sampling of the tree (default ``RRTOptions()``).

    Returns
    -------
    TreeResult
        Its ``plans`` (a list of :class:`riskplan.control.NominalPlan`, possibly empty:
        :func:`rrt_plans` raises :class:`~riskplan.errors.PlanningError` if all trees fail),
        nodes, parents, goal nodes and statistics.
    """
    cpu0 = time.process_time()
    _check_sim(sim)
    params = sim.nominal_params if params is None else params
    space = planning_space(sim) if space is None else space
    options = options or RRTOptions()
    if space.dim != sim.state_dim:
        raise InvalidInputError(
            f"space: has dimension {space.dim}, but sim.state_dim = {sim.state_dim}"
        )
    bounds = sampling_bounds(sim, options)
    r_tight = _goal_radius(sim, options)
    q = bounds.shape[0]
    if space.max_control_change is not None and space.max_control_change.shape != (q,):
        raise InvalidInputError(
            f"space.max_control_change: expected shape ({q},), got {space.max_control_change.shape}"
        )
    gen = as_generator(seed)
    root = sim.initial_state(params)
    x0 = np.asarray(sim.reduced(root), dtype=np.float64)
    tree = _Tree(root, x0, 0.5 * (bounds[:, 0] + bounds[:, 1]), q)
    growth = _Growth(sim, params, space, options, bounds, r_tight, gen, tree)
    it = 0
    while it < options.max_iterations and len(tree.goal_nodes) < options.plans_per_tree:
        it += 1
        growth.iterate()

    X = tree.X[: tree.n]
    best_node = int(np.argmin(space.distance(X, space.goal, to_goal=True)))
    best = float(sim.goal_distance(tree.node_state[best_node]))
    if tree.goal_nodes:
        best = min(best, min(float(sim.goal_distance(tree.node_state[g])) for g in tree.goal_nodes))
    plans = [
        _extract(sim, params, root, x0, tree.parents, tree.edge_states, tree.edge_controls, g)
        for g in tree.goal_nodes
    ]
    return TreeResult(
        seed=int(seed) if isinstance(seed, (int, np.integer)) else -1,
        plans=plans,
        nodes=X.copy(),
        parents=np.asarray(tree.parents, dtype=np.int64),
        goal_nodes=list(tree.goal_nodes),
        iterations=it,
        best_goal_distance=best,
        n_sim_steps=growth.n_steps,
        cpu_s=time.process_time() - cpu0,
    )


def _extract(sim, params, root, x0, parents, edge_states, edge_controls, leaf: int):
    from riskplan.control import NominalPlan

    chain = []
    node = leaf
    while node > 0:
        chain.append(node)
        node = parents[node]
    chain.reverse()
    states = [root]
    controls = []
    for node in chain:
        states.extend(edge_states[node])
        controls.append(edge_controls[node])
    reduced = np.stack([x0] + [np.asarray(sim.reduced(s), dtype=np.float64) for s in states[1:]])
    return NominalPlan(
        states=tuple(states), controls=np.concatenate(controls), reduced=reduced, params=params
    )


def _tree_task(args) -> TreeResult:
    sim, seed, params, space, options = args
    return grow_tree(sim, seed=seed, params=params, space=space, options=options)


def _add_distinct(plans: list, seen: set, results) -> int:
    """Append the trees' plans to ``plans`` except those whose controls are in ``seen``
    (updated); the number left out. The trees share the root, and steered edges are
    deterministic: a path of steered edges can recur in several trees; it is kept once."""
    repeats = 0
    for r in results:
        for p in r.plans:
            key = p.controls.tobytes()
            if key in seen:
                repeats += 1
                continue
            seen.add(key)
            plans.append(p)
    return repeats


def rrt_plans(
    sim,
    n_plans: int = 100,
    *,
    seed=0,
    params=None,
    space: PlanningSpace | None = None,
    options: RRTOptions | None = None,
    max_rounds: int = 4,
    backend: str = "local",
    workers: int | None = None,
    on_tree=None,
) -> tuple[list, list[TreeResult]]:
    """``n_plans`` distinct candidate plans (paper IV-A: "multiple such plans are extracted").

    Grows ``ceil(n_plans / options.plans_per_tree)`` trees (:func:`grow_tree`) with seeds
    ``spawn_seeds(seed, ...)`` in parallel; a plan whose controls repeat an earlier tree's
    (a path of deterministic steered edges from the shared root) is kept once; if they
    collect fewer distinct plans than asked, up to
    ``max_rounds − 1`` further rounds of trees (the next seeds of the same sequence) run
    for the rest. The plans do not depend on ``backend`` or ``workers``.

    Parameters
    ----------
    sim : PlanningScenario
        The simulator (as in :func:`grow_tree`).
    n_plans : int
        Plans wanted.
    seed : int or None
        Root of the trees' seeds.
    params : SimParams, optional
        The planning parameters (default ``sim.nominal_params``).
    space : PlanningSpace, optional
        The space to plan in (default :func:`planning_space` of ``sim``).
    options : RRTOptions, optional
        Budget and sampling of each tree (default ``RRTOptions()``).
    max_rounds : int
        Rounds of trees at most.
    backend, workers
        As in :func:`riskplan.parallel.map_tasks`.
    on_tree : callable, optional
        ``on_tree(index, tree)``, called as trees finish.

    Returns
    -------
    plans : list of riskplan.control.NominalPlan
        The first ``n_plans`` distinct plans (no two with the same controls) in tree
        order (fewer, with a warning, if the budget ran out).
    trees : list of TreeResult
        Every tree grown (their ``plans`` as each tree found them, repeats included).

    Raises
    ------
    PlanningError
        Naming the trees' sizes and the best goal distance, when no tree reached the goal.
    """
    from riskplan.parallel import map_tasks, spawn_seeds

    _check_sim(sim)
    n_plans = check_count(n_plans, "n_plans", 1)  # None, text, 1.5: named, not a TypeError
    max_rounds = check_count(max_rounds, "max_rounds", 1)
    if options is not None and not isinstance(options, RRTOptions):
        raise InvalidInputError(f"options: expected an RRTOptions, got {type(options).__name__}")
    params = sim.nominal_params if params is None else params
    space = planning_space(sim) if space is None else space
    options = options or RRTOptions()
    per = options.plans_per_tree
    first = -(-int(n_plans) // per)
    seeds = spawn_seeds(seed, first * max_rounds + int(n_plans))
    trees: list[TreeResult] = []
    plans: list = []
    seen: set[bytes] = set()
    repeats = 0
    used = 0
    for _ in range(int(max_rounds)):
        missing = int(n_plans) - len(plans)
        if missing <= 0:
            break
        n_trees = -(-missing // per)
        batch = seeds[used : used + n_trees]
        offset = len(trees)
        # a single tree for fewer plans than a tree collects stops at what is missing
        opts = options if missing >= per else dataclasses.replace(options, plans_per_tree=missing)
        cb = None if on_tree is None else (lambda i, r, _o=offset: on_tree(_o + i, r))
        results = map_tasks(
            _tree_task,
            [(sim, s, params, space, opts) for s in batch],
            backend=backend,
            workers=workers,
            on_result=cb,
        )
        used += n_trees
        trees.extend(results)
        repeats += _add_distinct(plans, seen, results)
    if not plans:
        sizes = [t.size for t in trees]
        best = min(t.best_goal_distance for t in trees)
        raise PlanningError(
            f"simulator RRT: no plan reached the goal in {len(trees)} trees of {options.max_iterations} iterations "
            f"(tree sizes {min(sizes)}..{max(sizes)} nodes, best goal distance {best:.4g}); "
            "raise options.max_iterations or n_controls, or check that the goal is reachable"
        )
    if repeats:
        log.info("simulator RRT: %d plans repeated an earlier tree's and were dropped", repeats)
    if len(plans) < n_plans:
        log.warning(
            "simulator RRT: %d of %d plans within the budget (%d trees)",
            len(plans),
            n_plans,
            len(trees),
        )
    return plans[: int(n_plans)], trees
