"""Collision risk along plans (MDN paper section V, eqs. 9-10) and the least-risk roadmap search.

``ConfigurationBound`` evaluates eq. 9 for configurations (the weighted mixture bound of the
predicted geometry distribution); eq. 10 combines a trajectory's per-configuration bounds,
``P(tau) <= 1 - prod_t (1 - p_t)``.

Beyond the paper (its stated future work: fold the risk into the planner): the least-risk
search prices every configuration ``x`` of a plan at ``-log(1 - p(x))``. Summed over a
trajectory these costs are ``-log prod_t (1 - p_t) = -log(1 - P_eq10)``, so the path of least
total cost is exactly the roadmap path whose interpolated trajectory has the smallest eq.-10
bound. A roadmap edge costs its interior configurations (the trajectory step, see
:func:`~riskplan.planning.prm.interpolate_path`) plus half of each end milestone; the start
and goal are on every path, so halving the milestones changes no comparison.
"""

from __future__ import annotations

import logging

import numpy as np

from riskplan._validation import check_count
from riskplan.collision import mixture_bound, trajectory_probability
from riskplan.planning.prm import DEFAULT_STEP, Roadmap, check_step, interpolate_path

log = logging.getLogger(__name__)


class ConfigurationBound:
    """Eq. 9 at configurations: ``(N, m) -> (N,)`` upper bounds on P(collision) (weighted mixture bound).

    ``model.predict`` gives the mixtures (base frame); ``environment`` is in the same frame.
    ``evaluations`` counts configurations evaluated (the optimisers' budget unit).
    """

    def __init__(self, model, environment, *, batch: int = 64):
        self.model = model
        self.environment = environment
        self.batch = int(batch)
        self.evaluations = 0

    def __call__(self, configs) -> np.ndarray:
        c = np.atleast_2d(np.asarray(configs, dtype=np.float64))
        out = np.empty(len(c))
        for i in range(0, len(c), self.batch):
            gm = self.model.predict(c[i : i + self.batch])
            out[i : i + self.batch] = mixture_bound(gm, self.environment, validate=False)
        self.evaluations += len(c)
        return out


#: share of a component's variance that moves the whole body (see :class:`CloudRiskBound`)
DEFAULT_COHERENCE = 0.15


class CloudRiskBound:
    """Body-contact risk at configurations from the learned model: ``(N, m) -> (N,)``
    (:func:`riskplan.collision.body_risk.cloud_risk`, beyond the paper).

    The fraction of body clouds drawn from the predicted mixture (``n_points`` points, one
    shared execution draw with share ``coherence`` of each component's variance) that touch an
    obstacle. The draws are the same for every configuration (``seed``), so the risk is a
    deterministic function of the configuration, as the optimisers need. Combined along a
    trajectory by :func:`trajectory_risk` it is eq. 10's product, an upper bound of the
    common-draw trajectory risk (one execution's draw is positively associated along a path).
    ``evaluations`` counts configurations evaluated.

    Default coherence :data:`DEFAULT_COHERENCE`: the share of the predicted tip component's
    variance that the executions themselves produce on the ``paper`` robot (tip standard deviation
    over 200 executions about 2.0 mm against the tip component's 5.2 mm, ratio of variances 0.13,
    10-90 % range 0.09-0.18 over 40 configurations near contact; docs/validation.md).
    """

    def __init__(
        self,
        model,
        environment,
        *,
        coherence: float | None = None,
        n_points: int = 512,
        n_clouds: int = 256,
        seed: int = 0,
    ):
        from riskplan.errors import InvalidInputError

        coherence = DEFAULT_COHERENCE if coherence is None else coherence
        if not (np.isfinite(coherence) and 0.0 <= coherence <= 1.0):
            raise InvalidInputError(f"coherence: expected a number in [0, 1], got {coherence!r}")
        self.model = model
        self.environment = environment
        self.coherence = float(coherence)
        self.n_points = int(n_points)
        self.n_clouds = int(n_clouds)
        self.seed = int(seed)
        self.evaluations = 0

    def __call__(self, configs) -> np.ndarray:
        from riskplan.collision.body_risk import cloud_risk

        c = np.atleast_2d(np.asarray(configs, dtype=np.float64))
        out = np.empty(len(c))
        for i, x in enumerate(c):
            gm = self.model.predict(x[None])
            out[i] = cloud_risk(
                gm,
                self.environment,
                n_points=self.n_points,
                n_clouds=self.n_clouds,
                coherence=self.coherence,
                seed=self.seed,
            ).per_configuration[0]
        self.evaluations += len(c)
        return out


class SampledBodyRisk:
    """Body-contact risk at configurations as a mixture over sampled whole bodies: ``(N, m) -> (N,)``
    (:func:`riskplan.collision.body_risk.sampled_body_risk`, beyond the paper).

    Each of ``n_draws`` samples is one execution of the robot's transmission (random start,
    the run's play widths and zero offsets, the play operator:
    :func:`~riskplan.planning.executions.execution_displacements`, the law the robot file states
    and the data were generated with); the learned model, evaluated at the configuration that
    execution delivers, places the whole body; a component's surface spread is its predicted
    covariance less the executions' share. The draws are the same for every call (``seed``), so
    the risk is a deterministic function of the configuration. :meth:`trajectory` gives the
    common-draw trajectory risk (each execution keeps its start, play and offset along the path).

    ``model``: an MDN model with ``robot`` (its :class:`~riskplan.robots.TendonRobot`) or a
    :class:`~riskplan.planning.robot_plan.ScaledModel` of one (configurations then in planning
    coordinates). ``evaluations`` counts configurations evaluated.
    """

    def __init__(
        self,
        model,
        environment,
        *,
        n_draws: int = 128,
        extent: float | None = None,
        seed: int = 0,
        batch: int = 16,
    ):
        from riskplan.collision.body_risk import DEFAULT_EXTENT
        from riskplan.errors import InvalidInputError
        from riskplan.parallel import spawn_seeds

        extent = DEFAULT_EXTENT if extent is None else extent
        if not (np.isfinite(extent) and extent > 0):
            raise InvalidInputError(f"extent: expected a finite number > 0, got {extent!r}")
        check_count(n_draws, "n_draws", 2, integral=True)
        base = getattr(model, "model", model)
        self.robot = getattr(base, "robot", None)
        if self.robot is None:
            raise InvalidInputError(
                "model: the sampled-body risk needs the model's robot (its transmission law)"
            )
        self.model = model
        self.environment = environment
        self.extent = float(extent)
        self.n_draws = int(n_draws)
        self.seed = int(seed)
        self.batch = int(batch)
        from riskplan.planning.executions import execution_draws

        self.draws = execution_draws(self.robot, spawn_seeds(self.seed, self.n_draws))
        self.evaluations = 0

    def _to_model(self, configs):
        to_model = getattr(self.model, "to_model", None)
        return configs if to_model is None else to_model(configs)

    def _to_planning(self, configs):
        to_planning = getattr(self.model, "to_planning", None)
        return configs if to_planning is None else to_planning(configs)

    def _draws(self, trajectory):
        """Nominal mixtures ``(T,)`` and the sampled executions' component means ``(S, T, K, 3)``
        of ``trajectory (T, m)`` (planning coordinates)."""
        from riskplan.gaussian_mixture import as_numpy_mixture
        from riskplan.planning.executions import execution_displacements

        y = np.atleast_2d(np.asarray(trajectory, dtype=np.float64))
        x = np.atleast_2d(self._to_model(y))
        eff = execution_displacements(self.robot, x, draws=self.draws)  # (S, T, m)
        S, T, m = eff.shape
        nominal = as_numpy_mixture(self.model.predict(y))
        drawn = as_numpy_mixture(self.model.predict(self._to_planning(eff.reshape(S * T, m))))
        return nominal, drawn.means.reshape(S, T, *drawn.means.shape[-2:])

    def _risk(self, trajectory):
        """:class:`~riskplan.collision.body_risk.CloudRisk` of ``trajectory (T, m)`` (planning coordinates)."""
        from riskplan.collision.body_risk import sampled_body_risk

        nominal, means = self._draws(trajectory)
        return sampled_body_risk(
            nominal, means, self.environment, extent=self.extent, validate=False
        )

    def gaps(self, trajectory) -> np.ndarray:
        """Clearance of each sampled execution's body along a trajectory
        (:func:`riskplan.collision.body_risk.sampled_body_gaps`).

        Parameters
        ----------
        trajectory : array_like
            ``(T, m)`` configurations (planning coordinates of ``model``); one configuration
            alone is a trajectory of ``T = 1``.

        Returns
        -------
        numpy.ndarray
            ``(S, T)`` clearances [m] of the ``S = n_draws`` sampled executions, each keeping
            its draw along the trajectory.
        """
        from riskplan.collision.body_risk import sampled_body_gaps

        nominal, means = self._draws(trajectory)
        return sampled_body_gaps(
            nominal, means, self.environment, extent=self.extent, validate=False
        )

    def __call__(self, configs) -> np.ndarray:
        """Risk per configuration.

        Parameters
        ----------
        configs : array_like
            ``(N, m)`` configurations (planning coordinates of ``model``).

        Returns
        -------
        numpy.ndarray
            ``(N,)`` fractions of the sampled executions whose body touches an obstacle.
        """
        c = np.atleast_2d(np.asarray(configs, dtype=np.float64))
        out = np.array([self._risk(x[None]).per_configuration[0] for x in c])
        self.evaluations += len(c)
        return out

    def trajectory(self, trajectory) -> float:
        """Common-draw risk that the body touches an obstacle somewhere along a trajectory.

        Parameters
        ----------
        trajectory : array_like
            ``(T, m)`` configurations (planning coordinates of ``model``).

        Returns
        -------
        float
            Fraction of the sampled executions (each keeps its draw along the path) whose
            body touches an obstacle at some configuration.
        """
        self.evaluations += len(np.atleast_2d(trajectory))
        return self._risk(trajectory).trajectory


#: risks the chest planner can optimise: the paper's eq. 9, the body-contact cloud risk and
#: the sampled-body risk (docs/validation.md compares them with the robot)
RISKS = ("eq9", "cloud", "bodies")


def make_risk(name: str, model, environment, **options):
    """The configuration risk ``name`` (:data:`RISKS`) for ``model`` in ``environment``."""
    from riskplan.errors import InvalidInputError

    if name == "eq9":
        return ConfigurationBound(model, environment)
    if name == "cloud":
        return CloudRiskBound(model, environment, **options)
    if name == "bodies":
        return SampledBodyRisk(model, environment, **options)
    raise InvalidInputError(f"risk: expected one of {RISKS}, got {name!r}")


def trajectory_risk(bound, trajectory) -> tuple[float, np.ndarray]:
    r"""The eq.-10 bound of a trajectory and its per-configuration eq.-9 bounds (MDN paper V).

    .. math::

        p(\exists x \in \tau : x \notin X_f) \le 1 - \prod_{x \in \tau} \left(1 - p(x \notin X_f)\right)

    Parameters
    ----------
    bound : callable
        ``bound(configs (T, m)) -> (T,)``, the eq.-9 bound of each configuration (e.g. a
        :class:`ConfigurationBound`).
    trajectory : array_like
        ``(T, m)`` configurations.

    Returns
    -------
    risk : float
        The eq.-10 bound.
    bounds : numpy.ndarray
        ``(T,)`` the per-configuration bounds.
    """
    p = bound(trajectory)
    return float(trajectory_probability(p)), p


def risk_cost(p) -> np.ndarray:
    """``-log(1 - p)`` (additive along a trajectory; ``inf`` for p = 1)."""
    with np.errstate(divide="ignore"):
        return -np.log1p(-np.clip(np.asarray(p, dtype=np.float64), 0.0, 1.0))


class RiskSegmentCost:
    """Segment cost for :meth:`Roadmap.graph_with`: interior configurations' ``-log(1 - p)`` plus
    half of each end's. Caches the bounds of roadmap milestones and of configurations seen."""

    def __init__(self, bound, step: float = DEFAULT_STEP):
        self.bound = bound
        self.step = check_step(step)
        self._cache: dict[bytes, float] = {}

    def costs(self, configs) -> np.ndarray:
        c = np.atleast_2d(np.asarray(configs, dtype=np.float64))
        keys = [x.tobytes() for x in c]
        todo = [i for i, k in enumerate(keys) if k not in self._cache]
        if todo:
            todo_unique = list(dict.fromkeys(keys[i] for i in todo))
            idx = {k: i for i, k in enumerate(keys)}
            p = self.bound(c[[idx[k] for k in todo_unique]])
            self._cache.update(zip(todo_unique, risk_cost(p)))
        return np.array([self._cache[k] for k in keys])

    def __call__(self, a, b) -> np.ndarray:
        a = np.atleast_2d(a)
        b = np.atleast_2d(b)
        interiors = [
            interpolate_path(np.stack([x, y]), self.step, validate=False)[1:-1]
            for x, y in zip(a, b)
        ]
        counts = np.array([len(x) for x in interiors])
        flat = np.concatenate(interiors + [np.empty((0, a.shape[1]))])
        # Sum over the non-empty groups only: their starts are strictly increasing and inside
        # ``flat``. (add.reduceat raises IndexError for a trailing empty group, whose start
        # equals len(flat), and copies the next value for an empty group elsewhere.)
        starts = np.cumsum(counts) - counts
        inner = np.zeros(len(a))
        full = counts > 0
        if full.any():
            inner[full] = np.add.reduceat(self.costs(flat), starts[full])
        return inner + 0.5 * (self.costs(a) + self.costs(b))


def least_risk_path(
    roadmap: Roadmap,
    bound,
    start,
    goal,
    *,
    step: float = DEFAULT_STEP,
    cost: RiskSegmentCost | None = None,
    progress=None,
) -> np.ndarray:
    r"""Roadmap path whose trajectory (interpolated at ``step``) has the least eq.-10 bound.

    Dijkstra with lazily priced edges: an edge's configurations are evaluated only when the
    search settles one of its ends, and the search stops when it settles the goal, so
    milestones riskier than the answer are never priced. The edge cost is additive,
    :math:`-\log(1 - p)` summed over the configurations.

    Parameters
    ----------
    roadmap : Roadmap
        The PRM.
    bound : callable
        ``bound(configs (N, m)) -> (N,)``, the eq.-9 bound.
    start, goal : array_like
        ``(m,)`` configurations.
    step : float
        Interpolation step of the trajectory.
    cost : RiskSegmentCost, optional
        A cost with its cache (shared between searches).
    progress : callable, optional
        ``progress(settled, total)`` reports the milestones settled so far.

    Returns
    -------
    numpy.ndarray
        ``(P, m)`` the path's vertices.
    """
    import heapq

    from riskplan.errors import PlanningError

    start, goal = roadmap.check_query(start, goal)
    cost = cost or RiskSegmentCost(bound, step)
    V = roadmap.n_vertices
    conf = np.vstack([roadmap.vertices, start[None], goal[None]])
    adj: list[list[int]] = [[] for _ in range(V + 2)]
    for a, b in roadmap.edges:
        adj[a].append(int(b))
        adj[b].append(int(a))
    for node, c in ((V, start), (V + 1, goal)):
        for i in roadmap.connect(c)[0]:
            adj[node].append(int(i))
            adj[int(i)].append(node)
    if (
        np.linalg.norm(goal - start) > 0
        and roadmap.validity.motions(start[None], goal[None], roadmap.resolution)[0]
    ):
        adj[V].append(V + 1)
        adj[V + 1].append(V)
    dist = np.full(V + 2, np.inf)
    pred = np.full(V + 2, -1)
    done = np.zeros(V + 2, dtype=bool)
    dist[V] = 0.0
    heap = [(0.0, V)]
    settled = 0
    while heap:
        d, u = heapq.heappop(heap)
        if done[u]:
            continue
        done[u] = True
        settled += 1
        if progress is not None:
            progress(settled, V + 2)
        if u == V + 1:
            break
        nb = [w for w in adj[u] if not done[w]]
        if not nb:
            continue
        c = cost(np.broadcast_to(conf[u], (len(nb), conf.shape[1])), conf[nb])
        for w, cw in zip(nb, c):
            if d + cw < dist[w]:
                dist[w] = d + cw
                pred[w] = u
                heapq.heappush(heap, (dist[w], w))
    if not done[V + 1] or not np.isfinite(dist[V + 1]):
        raise PlanningError(
            f"no path from start to goal in the roadmap ({roadmap.describe()}); grow it with more milestones "
            "(--milestones) or move the goal"
        )
    nodes = [V + 1]
    while nodes[-1] != V:
        nodes.append(int(pred[nodes[-1]]))
    return conf[nodes[::-1]]


def compare_paths(
    roadmap: Roadmap, bound, start, goal, *, step: float = DEFAULT_STEP, progress=None
) -> dict:
    """Shortest against least-risk roadmap path.

    Parameters
    ----------
    roadmap : Roadmap
        The PRM.
    bound : callable
        ``bound(configs (N, m)) -> (N,)``, the eq.-9 bound.
    start, goal : array_like
        ``(m,)`` configurations.
    step : float
        Interpolation step of the trajectories.
    progress : callable, optional
        As in :func:`least_risk_path`.

    Returns
    -------
    dict
        ``{"shortest": ..., "least_risk": ...}``, each with ``path``, ``trajectory``,
        per-configuration ``bounds``, the eq.-10 ``bound`` and the path ``length``.
    """
    out = {}
    cost = RiskSegmentCost(bound, step)
    for name, path in (
        ("shortest", roadmap.shortest_path(start, goal)),
        (
            "least_risk",
            least_risk_path(roadmap, bound, start, goal, step=step, cost=cost, progress=progress),
        ),
    ):
        traj = interpolate_path(path, step)
        p = -np.expm1(-cost.costs(traj))  # from the cache
        out[name] = {
            "path": path,
            "trajectory": traj,
            "bounds": p,
            "bound": float(trajectory_probability(p)),
            "length": float(np.linalg.norm(np.diff(path, axis=0), axis=-1).sum()),
        }
    return out
