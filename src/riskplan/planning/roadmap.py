"""What a roadmap query works with (MDN paper section V): the validity of configurations and
straight motions (every component mean of the predicted mixture in free space, the paper's
condition), and the :class:`Roadmap` container with its graph search.

:func:`riskplan.planning.build_roadmap` grows the roadmap with OMPL (``prm.py``); the
queries here (shortest path; the least-risk path of :mod:`riskplan.planning.risk`) run
Dijkstra on the graph read back from OMPL, with the start and goal connected to their
``k`` nearest valid milestones.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from riskplan._validation import as_array
from riskplan.errors import InvalidInputError, PlanningError
from riskplan.gaussian_mixture import as_numpy_mixture

DEFAULT_RESOLUTION = 1e-3  # m, motion check spacing (Euclidean, displacement space)


class MeanValidity:
    """Validity of configurations: within limits and every component mean in free space.

    ``model``: anything with ``predict(configs (N, m))`` returning a mixture (a torch
    ``GaussianMixture`` or a :class:`~riskplan.gaussian_mixture.NumpyMixture`) and
    ``limits (m, 2)`` (an :class:`~riskplan.kinematics.MDNModel`); ``environment``: an
    :class:`~riskplan.collision.Environment` in the model's (robot base) frame.
    """

    def __init__(self, model, environment):
        self.model = model
        self.environment = environment
        self.limits = np.asarray(model.limits, dtype=np.float64)
        self.n = self.limits.shape[0]
        self.checks = 0

    def within_limits(self, configs) -> np.ndarray:
        """Whether each configuration is finite and inside the limits.

        Parameters
        ----------
        configs : array_like, shape (N, m)
            Model inputs (tendon displacements in m, then any base motion).

        Returns
        -------
        numpy.ndarray, shape (N,)
            bool.
        """
        c = np.asarray(configs, dtype=np.float64)
        return np.all((c >= self.limits[:, 0]) & (c <= self.limits[:, 1]), axis=-1) & np.all(
            np.isfinite(c), axis=-1
        )

    def means(self, configs) -> np.ndarray:
        """Component means of the mixtures the model predicts.

        Parameters
        ----------
        configs : array_like, shape (N, m)
            Configurations within the limits.

        Returns
        -------
        numpy.ndarray, shape (N, K, 3)
            The means (m, robot base frame).
        """
        gm = self.model.predict(np.asarray(configs, dtype=np.float64))
        return as_numpy_mixture(gm, validate=False).means

    def __call__(self, configs) -> np.ndarray:
        """``(N, m) -> (N,)`` bool: within limits and no component mean inside an obstacle."""
        c = np.atleast_2d(np.asarray(configs, dtype=np.float64))
        ok = self.within_limits(c)
        if ok.any():
            mu = self.means(c[ok])
            self.checks += len(mu)
            inside = self.environment.contains(mu.reshape(-1, 3)).reshape(mu.shape[:2])
            ok[np.flatnonzero(ok)] = ~inside.any(-1)
        return ok

    def motions(self, starts, ends, resolution: float = DEFAULT_RESOLUTION) -> np.ndarray:
        """Validity of straight motions ``starts -> ends``, all checked in one batch.

        Motion ``i`` is checked at ``ceil(|b_i - a_i| / resolution) + 1`` equally spaced
        configurations including both ends; in a scene of walls (``crossing_check``) no
        component mean may also cross a surface between consecutive ones.

        Parameters
        ----------
        starts, ends : array_like, shape (N, m)
            The motions' ends.
        resolution : float
            Largest spacing of the checked configurations (Euclidean norm, m).

        Returns
        -------
        numpy.ndarray, shape (N,)
            bool.
        """
        a = np.atleast_2d(np.asarray(starts, dtype=np.float64))
        b = np.atleast_2d(np.asarray(ends, dtype=np.float64))
        counts = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=-1) / resolution).astype(int)) + 1
        owner = np.repeat(np.arange(len(a)), counts)
        t = np.concatenate([np.linspace(0.0, 1.0, k) for k in counts])
        pts = a[owner] + t[:, None] * (b - a)[owner]
        ok = self(pts)
        if getattr(self.environment, "crossing_check", False):
            ok &= self._no_crossing(pts, owner)
        return np.logical_and.reduceat(ok, np.concatenate([[0], np.cumsum(counts)[:-1]]))

    def _no_crossing(self, pts, owner) -> np.ndarray:
        """For surfaces that need not be closed (walls): ``(P,)`` False where a component mean
        crosses a surface on its way from the previous configuration of the same motion."""
        ok = np.ones(len(pts), dtype=bool)
        inside = self.within_limits(pts)
        same = np.flatnonzero((owner[1:] == owner[:-1]) & inside[1:] & inside[:-1]) + 1
        if same.size:
            sel = np.unique(np.concatenate([same - 1, same]))  # within the limits
            pos = np.full(len(pts), -1)
            pos[sel] = np.arange(len(sel))
            mu = self.means(pts[sel])  # (len(sel), K, 3)
            hit = self.environment.segments_collide(mu[pos[same - 1]], mu[pos[same]]).any(-1)
            ok[same[hit]] = False
        return ok


@dataclass
class Roadmap:
    """A PRM roadmap: milestones ``(V, m)``, undirected edges ``(E, 2)`` with lengths ``(E,)``.

    Build with :func:`~riskplan.planning.build_roadmap`; query with :meth:`shortest_path` or
    :func:`riskplan.planning.risk.least_risk_path`.
    """

    vertices: np.ndarray
    edges: np.ndarray
    validity: MeanValidity = field(repr=False)
    seed: int
    resolution: float
    n_neighbours: int
    build_seconds: float
    ompl_seeded: bool = False
    n_milestones: int = 0  # OMPL's count; milestones without edges are not in ``vertices``

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_edges(self) -> int:
        return len(self.edges)

    @property
    def edge_lengths(self) -> np.ndarray:
        v = self.vertices
        return np.linalg.norm(v[self.edges[:, 1]] - v[self.edges[:, 0]], axis=-1)

    def describe(self) -> str:
        """One line for logs and errors.

        Returns
        -------
        str
            Milestones (and how many are connected), edges and the build time (s).
        """
        return (
            f"{max(self.n_milestones, self.n_vertices)} milestones ({self.n_vertices} connected), "
            f"{self.n_edges} edges, built in {self.build_seconds:.1f} s"
        )

    def connect(self, config) -> tuple[np.ndarray, np.ndarray]:
        """The milestones reachable from ``config`` by a valid straight motion, among its
        ``n_neighbours`` nearest.

        Parameters
        ----------
        config : numpy.ndarray, shape (m,)
            A configuration (planning coordinates).

        Returns
        -------
        indices : numpy.ndarray, shape (k,)
            Milestone indices, nearest first.
        lengths : numpy.ndarray, shape (k,)
            Their Euclidean distances from ``config``.
        """
        d = np.linalg.norm(self.vertices - config, axis=-1)
        near = np.argsort(d, kind="stable")[: self.n_neighbours]
        ok = self.validity.motions(
            np.broadcast_to(config, (len(near), len(config))), self.vertices[near], self.resolution
        )
        return near[ok], d[near[ok]]

    def graph_with(self, start, goal, segment_cost=None, edge_costs=None):
        """Sparse symmetric cost graph of the roadmap plus the start (node V) and the goal (V + 1).

        The start and goal connect to their nearest valid milestones (:meth:`connect`), and to
        each other if that motion is valid. A cost of zero is raised to ``1e-300`` (a sparse
        graph reads zero as "no edge").

        Parameters
        ----------
        start, goal : numpy.ndarray, shape (m,)
            The query's ends (checked, :meth:`check_query`).
        segment_cost : callable, optional
            ``segment_cost(a (N, m), b (N, m)) -> (N,)`` prices a straight motion (default:
            its length).
        edge_costs : array_like, shape (E,), optional
            The roadmap edges' costs if already known.

        Returns
        -------
        scipy.sparse.csr_matrix, shape (V + 2, V + 2)
            The symmetric cost graph.
        """
        from scipy.sparse import coo_matrix

        cost = segment_cost or (lambda a, b: np.linalg.norm(b - a, axis=-1))
        V = self.n_vertices
        if edge_costs is None:
            edge_costs = cost(self.vertices[self.edges[:, 0]], self.vertices[self.edges[:, 1]])
        rows, cols, vals = (
            [self.edges[:, 0]],
            [self.edges[:, 1]],
            [np.asarray(edge_costs, dtype=np.float64)],
        )
        for node, conf in ((V, start), (V + 1, goal)):
            idx, _ = self.connect(conf)
            rows.append(np.full(len(idx), node))
            cols.append(idx)
            vals.append(cost(np.broadcast_to(conf, (len(idx), len(conf))), self.vertices[idx]))
        if (
            np.linalg.norm(goal - start) > 0
            and self.validity.motions(start[None], goal[None], self.resolution)[0]
        ):
            rows.append(np.array([V]))
            cols.append(np.array([V + 1]))
            vals.append(cost(start[None], goal[None]))
        r, c, v = (np.concatenate(x) for x in (rows, cols, vals))
        # a zero cost would read as "no edge" in a sparse graph
        v = np.maximum(v, 1e-300)
        g = coo_matrix(
            (np.concatenate([v, v]), (np.concatenate([r, c]), np.concatenate([c, r]))),
            shape=(V + 2, V + 2),
        )
        return g.tocsr()

    def search(self, graph, start, goal) -> np.ndarray:
        """Dijkstra from node V (the start) to V + 1 (the goal) of ``graph``.

        Parameters
        ----------
        graph : scipy.sparse.csr_matrix, shape (V + 2, V + 2)
            A cost graph of :meth:`graph_with`.
        start, goal : numpy.ndarray, shape (m,)
            The configurations of nodes V and V + 1.

        Returns
        -------
        numpy.ndarray, shape (P, m)
            The least-cost path's configurations, start to goal.

        Raises
        ------
        PlanningError
            The goal is not reachable in the roadmap.
        """
        from scipy.sparse.csgraph import dijkstra

        V = self.n_vertices
        dist, pred = dijkstra(graph, directed=False, indices=V, return_predecessors=True)
        if not np.isfinite(dist[V + 1]):
            raise PlanningError(
                f"no path from start to goal in the roadmap ({self.describe()}); grow it with more milestones "
                "(--milestones) or move the goal"
            )
        nodes = [V + 1]
        while nodes[-1] != V:
            nodes.append(int(pred[nodes[-1]]))
        nodes = nodes[::-1]
        allv = np.vstack([self.vertices, start[None], goal[None]])
        return allv[nodes]

    def shortest_path(self, start, goal) -> np.ndarray:
        """The shortest valid path (Euclidean length in planning coordinates).

        Parameters
        ----------
        start, goal : array_like, shape (m,)
            Valid configurations within the limits.

        Returns
        -------
        numpy.ndarray, shape (P, m)
            The path's configurations, start to goal.
        """
        start, goal = self.check_query(start, goal)
        return self.search(self.graph_with(start, goal), start, goal)

    def check_query(self, start, goal) -> tuple[np.ndarray, np.ndarray]:
        """A query's ends checked: well formed, within the limits and valid.

        Parameters
        ----------
        start, goal : array_like, shape (m,)
            The configurations.

        Returns
        -------
        start, goal : numpy.ndarray, shape (m,)
            float64 copies.

        Raises
        ------
        InvalidInputError
            Either is malformed, outside the limits or invalid.
        """
        m = self.vertices.shape[1]
        out = []
        for name, c in (("start", start), ("goal", goal)):
            c = as_array(c, name, shape=(m,))
            lim = self.validity.limits
            if not self.validity.within_limits(c[None])[0]:
                raise InvalidInputError(
                    f"{name}: {c.tolist()} is outside the displacement limits {lim.tolist()}"
                )
            if not self.validity(c[None])[0]:
                raise InvalidInputError(
                    f"{name}: configuration {c.tolist()} is invalid (a component mean of its predicted mixture lies inside an obstacle)"
                )
            out.append(c)
        return out[0], out[1]
