"""Chest-cavity planning pipeline (MDN paper section V, Figs. 6-7): roadmap, nominal
trajectory, Bayesian optimisation of its eq.-10 bound, optional least-risk roadmap path.

Frames: the learned model predicts mixtures in the robot *base* frame, so every environment
passed here is in the base frame (:attr:`riskplan.scenarios.chest.Chest.base_environment`, or
a user mesh mapped with :func:`riskplan.collision.load_environment`). Goal tips are base-frame points.

Default scene (issue part 3): start at zero displacement (the straight robot, free in the
procedural chest) and a goal tip in the effusion pocket, :data:`DEFAULT_GOAL_TIP`: 5 cm
caudal, 6 cm posterior and 17 cm medial of the port (base frame), i.e. in the posterior,
dependent part of the pocket just above the diaphragm dome, where a pleural effusion pools
(the posterior costophrenic recess). docs/planning.md lists the scan of pocket targets behind
this choice and the bound it gives; the bound is whatever eq. 10 says.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from riskplan._validation import as_array
from riskplan.errors import InvalidInputError
from riskplan.planning.bo import (
    OptimisationResult,
    OptimiserConfig,
    optimise_trajectory,
)
from riskplan.planning.prm import (
    DEFAULT_MILESTONES,
    DEFAULT_RESOLUTION,
    DEFAULT_STEP,
    DEFAULT_TIP_TOLERANCE,
    MeanValidity,
    Roadmap,
    build_roadmap,
    goal_from_tip,
    interpolate_path,
)
from riskplan.planning.risk import ConfigurationBound, compare_paths, trajectory_risk

log = logging.getLogger(__name__)

# base frame: x cranial, y anterior (z cross x), z medial (insertion direction); metres
DEFAULT_GOAL_TIP = (-0.05, -0.06, 0.17)


@dataclass
class ChestPlan:
    """Everything :func:`plan_chest` computed (arrays in displacement space, metres)."""

    roadmap: Roadmap
    start: np.ndarray
    goal: np.ndarray
    goal_tip: np.ndarray | None
    path: np.ndarray
    nominal: np.ndarray
    nominal_bounds: np.ndarray
    nominal_bound: float
    optimised: OptimisationResult
    paths: dict | None = None
    timings: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)


def _finite_positive(v, name):
    if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
        raise InvalidInputError(f"{name}: expected a finite number > 0, got {v!r}")
    return float(v)


def plan_chest(
    model,
    environment,
    *,
    start=None,
    goal=None,
    goal_tip=None,
    tip_tolerance: float = DEFAULT_TIP_TOLERANCE,
    n_milestones: int = DEFAULT_MILESTONES,
    step: float = DEFAULT_STEP,
    resolution: float = DEFAULT_RESOLUTION,
    optimiser: OptimiserConfig | None = None,
    seed: int = 0,
    least_risk: bool = False,
    checkpoint=None,
    resume: bool = False,
    roadmap_progress=None,
    optimise_progress=None,
    risk_progress=None,
) -> ChestPlan:
    """Plan a nominal trajectory with a PRM and lower its eq.-10 bound (paper section V).

    ``model``: an :class:`~riskplan.kinematics.MDNModel`; ``environment``: base-frame
    :class:`~riskplan.collision.Environment`; ``start``/``goal`` ``(m,)`` displacements (start
    default: zeros clipped to the limits), or ``goal_tip (3,)`` base frame (default
    :data:`DEFAULT_GOAL_TIP` when neither is given). ``least_risk``: also search the roadmap
    for the least-risk path (edge cost ``-log(1 - p)``) and report both paths' bounds.
    """
    optimiser = optimiser or OptimiserConfig()
    optimiser.validate()
    for name, v in (("step", step), ("resolution", resolution), ("tip_tolerance", tip_tolerance)):
        _finite_positive(v, name)
    if goal is not None and goal_tip is not None:
        raise InvalidInputError(
            "give either goal (displacements) or goal_tip (a tip target), not both"
        )
    lim = np.asarray(model.limits, dtype=np.float64)
    m = lim.shape[0]
    check_chest_budget(
        lim, n_milestones=n_milestones, step=step, resolution=resolution, optimiser=optimiser
    )
    if start is None:
        start = np.clip(np.zeros(m), lim[:, 0], lim[:, 1])
    start = as_array(start, "start", shape=(m,))
    if goal is not None:
        goal = as_array(goal, "goal", shape=(m,))
    elif goal_tip is None:
        goal_tip = DEFAULT_GOAL_TIP
    validity = MeanValidity(model, environment)
    for name, c in (("start", start), ("goal", goal)):
        if c is None:
            continue
        if not validity.within_limits(c[None])[0]:
            raise InvalidInputError(
                f"{name}: {c.tolist()} is outside the displacement limits {lim.tolist()}"
            )
        if not validity(c[None])[0]:
            raise InvalidInputError(
                f"{name}: configuration {c.tolist()} is invalid (a component mean of its predicted mixture lies inside an obstacle)"
            )

    timings = {}
    t = time.perf_counter()
    roadmap = build_roadmap(
        validity,
        n_milestones=n_milestones,
        seed=seed,
        resolution=resolution,
        progress=roadmap_progress,
    )
    timings["roadmap_s"] = time.perf_counter() - t
    if goal is None:
        goal_tip = as_array(goal_tip, "goal_tip", shape=(3,))
        goal = goal_from_tip(roadmap, model, goal_tip, tolerance=tip_tolerance, seed=seed)
    bound = ConfigurationBound(model, environment)
    t = time.perf_counter()
    paths = None
    if least_risk:
        paths = compare_paths(roadmap, bound, start, goal, step=step, progress=risk_progress)
        path = paths["shortest"]["path"]
    else:
        path = roadmap.shortest_path(start, goal)
    nominal = interpolate_path(path, step)
    nominal_bound, nominal_bounds = trajectory_risk(bound, nominal)
    timings["query_s"] = time.perf_counter() - t
    t = time.perf_counter()
    res = optimise_trajectory(
        nominal,
        bound,
        validity,
        lim,
        config=optimiser,
        seed=seed,
        bounds=nominal_bounds,
        checkpoint=checkpoint,
        resume=resume,
        progress=optimise_progress,
    )
    timings["optimise_s"] = time.perf_counter() - t
    settings = {
        "n_milestones": int(n_milestones),
        "step": step,
        "resolution": resolution,
        "seed": int(seed),
        "tip_tolerance": tip_tolerance,
        "neighbours": roadmap.n_neighbours,
        "optimiser": {
            k: getattr(optimiser, k)
            for k in ("iterations", "n_candidates", "radius", "method", "resolution")
        },
    }
    return ChestPlan(
        roadmap,
        start,
        goal,
        None if goal_tip is None else np.asarray(goal_tip, dtype=np.float64),
        path,
        nominal,
        nominal_bounds,
        nominal_bound,
        res,
        paths,
        timings,
        settings,
    )


#: least memory of one roadmap milestone (bytes): its coordinates, about k = 10 edges read back
#: from OMPL (two int64 each, shared by two milestones), the search's adjacency lists and its
#: distance, predecessor and settled arrays; OMPL's own copy of the graph comes on top
MILESTONE_BYTES = 250.0
#: least time of one configuration of one robot execution in the validation (s): a tenth of
#: the measured 0.39 ms of a Cosserat solve (docs/reproduce.md, 2-core AMD EPYC, shared)
ROBOT_CONFIG_S = 0.039e-3


def check_chest_budget(
    limits,
    *,
    n_milestones: int,
    step: float,
    resolution: float,
    optimiser: OptimiserConfig,
    executions: int = 0,
) -> None:
    """Refuse a chest plan whose work exceeds the budget (:mod:`riskplan.budget`), before any
    work, naming the option: the roadmap (``--milestones``; its motion checks at
    ``--resolution``, a motion about the typical neighbour distance ``diag / n^(1/m)`` long),
    the trajectory (``--step``; estimated for a path across the displacement box's diagonal),
    the optimiser (:func:`~riskplan.planning.bo.check_optimiser_budget`) and the validation
    (``--executions`` of the nominal and the optimised trajectory on the robot)."""
    from riskplan.budget import check_budget
    from riskplan.planning.bo import MOTION_STATE_BYTES, check_optimiser_budget

    lim = np.asarray(limits, dtype=np.float64)
    m = lim.shape[0]
    diag = float(np.linalg.norm(lim[:, 1] - lim[:, 0]))
    n = float(n_milestones)
    check_budget(
        f"a roadmap of {n_milestones} milestones", "--milestones", nbytes=n * MILESTONE_BYTES
    )
    neighbour = diag / max(n, 1.0) ** (1.0 / m)
    states = neighbour / resolution + 1
    check_budget(
        f"motion checks at resolution {resolution:g} ({states:.3g} states per motion)",
        "--resolution",
        nbytes=states * MOTION_STATE_BYTES * m,
    )
    T = diag / step + 2
    check_budget(
        f"a trajectory of about {T:.3g} configurations at step {step:g}",
        "--step",
        nbytes=T * 8.0 * m * 4,  # the trajectory, its bounds, the optimiser's copies
    )
    check_optimiser_budget(optimiser, int(min(T, 2**62)), lim)
    if executions:
        check_budget(
            f"{executions} robot executions of 2 trajectories of about {T:.3g} configurations",
            "--executions",
            seconds=2.0 * float(executions) * T * ROBOT_CONFIG_S,
        )
