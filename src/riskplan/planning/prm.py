"""Probabilistic roadmap in tendon-displacement space (MDN paper section V; Kavraki et al. 1996).

The configuration space is the box of the robot's tendon displacements (its limits). A
configuration is *valid* when every component mean of the mixture predicted by the learned
kinematic model lies in free space (not inside any obstacle of the environment, robot base
frame) — the paper's condition, which keeps eq. 9 well defined along the plan. A straight
motion between two configurations is valid when every configuration on it, spaced at most
``resolution`` (default 1 mm, Euclidean norm of the displacement vector) apart, is valid.

The roadmap is OMPL's ``PRM`` (``ompl.geometric``): milestones from a valid-state sampler,
each connected to its ``k`` nearest neighbours (OMPL's default ``k = 10``) through our motion
validator, which checks all states of a motion in one batched model call. Two choices keep
the roadmap reproducible:

* The roadmap grows until it holds ``n_milestones`` milestones (``growRoadmapPtc`` with a
  count-based termination condition), not for a wall-clock time: the same seed gives the same
  roadmap on any machine.
* Milestones are drawn by our own sampler from a NumPy generator seeded with ``seed``. OMPL's
  global ``ou.RNG.setSeed`` only takes effect before OMPL draws its first random number in a
  process, so a second roadmap in the same process would otherwise differ. We still call it
  (when it is still possible) for OMPL's internal generators, which do not influence the
  roadmap (nearest-neighbour results are exact whatever the GNAT pivots).

Queries (shortest path, least-risk path in :mod:`riskplan.planning.risk`) run Dijkstra on the
roadmap graph read back from OMPL (``getPlannerData``): the start and goal are connected to
their ``k`` nearest valid milestones, and the same roadmap answers any number of queries.
OMPL's own ``PRM.solve`` grows the roadmap in a second thread under a timed condition while it
searches, so its answer would depend on timing.

The nominal trajectory is the path with each segment split into ``ceil(length / step)`` equal
pieces (``step`` default 2.5 mm), so every segment contributes at most ``step`` of motion
between consecutive configurations and the trajectory's configurations are exactly those
of its edges (which makes the least-risk search exact, see ``risk.py``).
"""

from __future__ import annotations

import itertools
import logging
import math
import time

import numpy as np

from riskplan._validation import as_array, as_generator
from riskplan.errors import InvalidInputError, PlanningError
from riskplan.gaussian_mixture import as_numpy_mixture
from riskplan.planning.roadmap import DEFAULT_RESOLUTION, MeanValidity, Roadmap

log = logging.getLogger(__name__)

DEFAULT_STEP = 2.5e-3  # m, largest step between consecutive trajectory configurations
DEFAULT_MILESTONES = 300
DEFAULT_NEIGHBOURS = 10  # OMPL's PRM default (magic::DEFAULT_NEAREST_NEIGHBORS)
DEFAULT_TIP_TOLERANCE = 5e-3  # m
SAMPLER_ATTEMPTS = 100  # OMPL's UniformValidStateSampler default


def _check_positive(value, name: str) -> float:
    v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise InvalidInputError(f"{name}: expected a finite number > 0, got {value!r}")
    return v


def check_step(step, name: str = "step") -> float:
    """``step`` as a float, finite and > 0 (a normal number: a subnormal step overflows the
    piece counts), else :class:`~riskplan.errors.InvalidInputError` naming ``name``."""
    from riskplan.errors import InvalidInputError

    if isinstance(step, bool) or not isinstance(step, int | float | np.integer | np.floating):
        raise InvalidInputError(f"{name}: expected a number, got {step!r}")
    s = float(step)
    if not (math.isfinite(s) and s > 0):
        raise InvalidInputError(f"{name}: expected a finite number > 0, got {step!r}")
    if s < np.finfo(np.float64).tiny:
        raise InvalidInputError(f"{name}: {step!r} is subnormal; expected a normal float > 0")
    return s


def interpolate_path(path, step: float = DEFAULT_STEP, *, validate: bool = True) -> np.ndarray:
    """Split each segment of a path into ``ceil(length / step)`` equal pieces.

    The path's vertices are kept; consecutive configurations are at most ``step`` apart.

    Parameters
    ----------
    path : array_like
        ``(P, m)``, finite, ``P >= 1``.
    step : float
        Largest distance between consecutive configurations (finite, > 0).
    validate : bool
        Check the arguments and the work budget (:mod:`riskplan.budget`); ``False`` for
        internal callers with checked arguments.

    Returns
    -------
    numpy.ndarray
        ``(T, m)`` the trajectory.

    Raises
    ------
    InvalidInputError
        Bad arguments, or a trajectory beyond the work budget (``BudgetError``).
    """
    if validate:
        from riskplan._validation import as_array
        from riskplan.budget import check_budget

        p = as_array(path, "path", min_ndim=2)
        if p.ndim != 2 or p.shape[0] < 1 or p.shape[1] < 1:
            from riskplan.errors import InvalidInputError

            raise InvalidInputError(f"path: expected shape (P >= 1, m >= 1), got {p.shape}")
        step = check_step(step)
        with np.errstate(over="ignore"):
            n = float(np.sum(np.ceil(np.linalg.norm(np.diff(p, axis=0), axis=-1) / step))) + 1
        check_budget(
            f"a trajectory of {n:.3g} configurations",
            "step",
            # the pieces, their products and the concatenated result
            nbytes=3.0 * n * p.shape[1] * 8.0,
        )
    p = np.asarray(path, dtype=np.float64)
    out = [p[:1]]
    for a, b in itertools.pairwise(p):
        k = max(1, math.ceil(float(np.linalg.norm(b - a)) / step - 1e-12))
        t = np.arange(1, k + 1) / k
        seg = a + t[:, None] * (b - a)
        seg[-1] = b  # the vertex itself (a + (b - a) can differ from b by a rounding)
        out.append(seg)
    return np.concatenate(out)


def segment_owners(path, step: float = DEFAULT_STEP) -> np.ndarray:
    """For :func:`interpolate_path`: the segment index of every trajectory configuration ``(T,)``
    (``-1`` for the first)."""
    p = np.asarray(path, dtype=np.float64)
    own = [np.array([-1])]
    for i, (a, b) in enumerate(itertools.pairwise(p)):
        k = max(1, math.ceil(float(np.linalg.norm(b - a)) / step - 1e-12))
        own.append(np.full(k, i))
    return np.concatenate(own)


_OMPL_SEEDED: list[int] = []  # the seed given to OMPL in this process (at most one)


def _seed_ompl(seed: int) -> bool:
    """``ou.RNG.setSeed`` once per process, before OMPL draws its first random number.

    Returns whether OMPL's generators use ``seed`` (False for a later roadmap with another seed:
    OMPL ignores a new seed once generation started). The roadmap does not depend on it.
    """
    from ompl import util as ou

    ou.setLogLevel(ou.LogLevel.LOG_WARN)
    if not _OMPL_SEEDED:
        ou.RNG.setSeed(int(seed) % (2**31 - 2) + 1)  # OMPL rejects seed 0
        _OMPL_SEEDED.append(int(seed))
    return _OMPL_SEEDED[0] == int(seed)


def _planner_graph(ob, prm, si, m: int):
    """``(milestones (V, m), edges (E, 2) with i < j)`` of a grown OMPL PRM: the milestones
    that have edges (OMPL's planner data)."""
    pd = ob.PlannerData(si)
    prm.getPlannerData(pd)  # holds the milestones that have edges
    nv = pd.numVertices()
    verts = np.empty((nv, m))
    edges = []
    for v in range(nv):
        s = pd.getVertex(v).getState()
        verts[v] = [s[i] for i in range(m)]
        edges.extend((v, w) for w in pd.getEdges(v) if w > v)
    return verts, np.asarray(edges, dtype=np.int64).reshape(-1, 2)


def build_roadmap(
    validity: MeanValidity,
    *,
    n_milestones: int = DEFAULT_MILESTONES,
    seed: int = 0,
    n_neighbours: int = DEFAULT_NEIGHBOURS,
    resolution: float = DEFAULT_RESOLUTION,
    progress=None,
    max_seconds: float | None = None,
) -> Roadmap:
    """Grow an OMPL PRM to ``n_milestones`` valid milestones in the displacement box.

    Milestones come from a sampler seeded with ``seed`` and connect to their
    ``n_neighbours`` nearest through valid motions (see the module docstring): the same
    seed gives the same roadmap on any machine.

    Parameters
    ----------
    validity : MeanValidity
        Validity of configurations and motions; its ``limits (m, 2)`` are the box.
    n_milestones : int
        Milestones to grow (>= 2).
    seed : int
        Seed of the milestone sampler.
    n_neighbours : int
        Nearest milestones each new one tries to connect to (OMPL's ``k``).
    resolution : float
        Motion-check spacing (m, planning coordinates).
    progress : callable, optional
        ``progress(done, total)`` as milestones are added.
    max_seconds : float, optional
        Wall-clock limit (s) of the growth.

    Returns
    -------
    Roadmap
        The milestones that have edges ``(V, m)`` and the edges ``(E, 2)``.

    Raises
    ------
    PlanningError
        Growing took longer than ``max_seconds`` (a scene with almost no free space).
    """
    from ompl import base as ob
    from ompl import geometric as og

    if int(n_milestones) < 2:
        raise InvalidInputError(f"n_milestones: expected >= 2, got {n_milestones}")
    if int(n_neighbours) < 1:
        raise InvalidInputError(f"n_neighbours: expected >= 1, got {n_neighbours}")
    resolution = _check_positive(resolution, "resolution")
    rng = as_generator(seed)  # a named error for a bad seed before OMPL is seeded with it
    seeded = _seed_ompl(seed)
    stats = {"drawn": 0}
    t0 = time.perf_counter()
    # the motion validator is held here: OMPL keeps only a pointer to it
    si, _motion = _space_information(ob, validity, rng, resolution, stats)
    prm = og.PRM(si)
    prm.setMaxNearestNeighbors(int(n_neighbours))
    pdef = ob.ProblemDefinition(si)  # PRM's setup (nearest-neighbour structure) needs one
    prm.setProblemDefinition(pdef)
    prm.setup()
    total = int(n_milestones)
    state = {"timeout": False}

    def stop() -> bool:
        n = prm.milestoneCount()
        if progress is not None:
            progress(min(n, total), total)
        if max_seconds is not None and time.perf_counter() - t0 > max_seconds:
            state["timeout"] = True
            return True
        return n >= total

    prm.growRoadmapPtc(ob.PlannerTerminationCondition(stop))
    elapsed = time.perf_counter() - t0
    if state["timeout"]:
        raise PlanningError(
            f"roadmap growth stopped after {elapsed:.1f} s (limit {max_seconds} s) with {prm.milestoneCount()} of "
            f"{total} milestones ({stats['drawn']} configurations drawn); free space is too small for the model's means"
        )
    verts, E = _planner_graph(ob, prm, si, validity.n)
    log.info(
        "PRM: %d milestones (%d in OMPL), %d edges in %.2f s",
        len(verts),
        prm.milestoneCount(),
        len(E),
        elapsed,
    )
    return Roadmap(
        verts,
        E,
        validity,
        int(seed),
        resolution,
        int(n_neighbours),
        elapsed,
        seeded,
        prm.milestoneCount(),
    )


def _space_information(ob, validity: MeanValidity, rng, resolution: float, stats: dict):
    """OMPL's space of the displacement box with our validity checker, motion validator and
    seeded valid-state sampler; (space information, the motion validator)."""
    lim = validity.limits
    m = validity.n
    space = ob.RealVectorStateSpace(m)
    bounds = ob.RealVectorBounds(m)
    for i in range(m):
        bounds.setLow(i, float(lim[i, 0]))
        bounds.setHigh(i, float(lim[i, 1]))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)
    si.setStateValidityChecker(
        lambda s: bool(validity(np.array([s[i] for i in range(m)])[None])[0])
    )
    pending: list[np.ndarray] = []

    class _Sampler(ob.ValidStateSampler):
        # draws valid states in batches of 64 (one model call each) from the seeded generator
        def sample(self, state):
            for _ in range(SAMPLER_ATTEMPTS):
                if not pending:
                    cand = lim[:, 0] + rng.random((64, m)) * (lim[:, 1] - lim[:, 0])
                    stats["drawn"] += 64
                    pending.extend(cand[validity(cand)][::-1])
                    if not pending:
                        continue
                x = pending.pop()
                for i in range(m):
                    state[i] = float(x[i])
                return True
            return False

        def sampleNear(
            self, state, near, distance
        ):  # pragma: no cover - PRM's growth does not use it
            return False

    class _Motion(ob.MotionValidator):
        def checkMotion(self, s1, s2, *last):
            a = np.array([s1[i] for i in range(m)])
            b = np.array([s2[i] for i in range(m)])
            return bool(validity.motions(a[None], b[None], resolution)[0])

    motion = _Motion(si)
    si.setMotionValidator(motion)
    si.setValidStateSamplerAllocator(lambda s: _Sampler(s))
    si.setup()
    return si, motion


def tip_positions(model, configs) -> np.ndarray:
    """Predicted tip: the component mean farthest from the base origin.

    The mixture's components cover the robot's body; the farthest mean is the one that
    describes its distal end (the tip), in the base frame.

    Parameters
    ----------
    model : KinematicsModel
        The kinematics model (:class:`~riskplan.kinematics_model.KinematicsModel`; the
        learned :class:`~riskplan.kinematics.MDNModel` is one).
    configs : array_like
        ``(N, m)`` configurations.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` tip positions.
    """
    gm = model.predict(np.atleast_2d(np.asarray(configs, dtype=np.float64)))
    mu = as_numpy_mixture(gm, validate=False).means
    far = np.argmax(np.linalg.norm(mu, axis=-1), axis=-1)
    return mu[np.arange(len(mu)), far]


def goal_from_tip(
    roadmap: Roadmap,
    model,
    target,
    *,
    tolerance: float = DEFAULT_TIP_TOLERANCE,
    n_samples: int = 4096,
    seed: int = 0,
) -> np.ndarray:
    """A valid configuration whose predicted tip lies within ``tolerance`` of ``target``.

    Candidates: the roadmap's milestones and ``n_samples`` seeded uniform configurations; the
    valid candidate with the closest tip wins.

    Parameters
    ----------
    roadmap : Roadmap
        Its milestones are candidates and its validity check filters them.
    model : KinematicsModel
        The kinematics model (:func:`tip_positions`).
    target : array_like
        ``(3,)`` tip position in the base frame.
    tolerance : float
        Largest tip distance accepted.
    n_samples : int
        Uniform candidates besides the milestones.
    seed : int
        Seeds the candidates.

    Returns
    -------
    numpy.ndarray
        ``(m,)`` the configuration.

    Raises
    ------
    PlanningError
        No valid candidate is within ``tolerance``.
    """
    target = as_array(target, "goal_tip", shape=(3,))
    tolerance = _check_positive(tolerance, "tolerance")
    lim = roadmap.validity.limits
    rng = as_generator(seed)
    cand = np.vstack(
        [
            roadmap.vertices,
            lim[:, 0] + rng.random((int(n_samples), lim.shape[0])) * (lim[:, 1] - lim[:, 0]),
        ]
    )
    cand = cand[roadmap.validity(cand)]
    d = np.linalg.norm(tip_positions(model, cand) - target, axis=-1)
    best = int(np.argmin(d))
    if d[best] > tolerance:
        raise PlanningError(
            f"goal tip {target.tolist()} (base frame) is unreachable: the closest valid predicted tip among "
            f"{len(cand)} configurations is {d[best] * 1e3:.1f} mm away (tolerance {tolerance * 1e3:.1f} mm)"
        )
    # refine locally within the tolerance ball: a few seeded perturbations around the best
    x = cand[best]
    for scale in (2e-3, 1e-3, 5e-4):
        loc = np.clip(x + scale * rng.standard_normal((256, len(x))), lim[:, 0], lim[:, 1])
        loc = loc[roadmap.validity(loc)]
        if len(loc):
            dl = np.linalg.norm(tip_positions(model, loc) - target, axis=-1)
            if dl.min() < d[best]:
                x, d[best] = loc[int(np.argmin(dl))], dl.min()
    return x
