"""Scenario 2 of the deformable-planning paper (Patil, van den Berg & Alterovitz, RSS 2011,
section V-B): external manipulation of a planar deformable object to move an internal
target point into a goal region while the object avoids a static obstacle.

Object: a unit square with its bottom-right corner cut off; the cut edge (the
"bottom-right edge") is fixed. Three manipulators hold the object at boundary material
points and push/pull it with force vectors ``F_k`` (the controls,
``u = (F_1x, F_1y, F_2x, F_2y, F_3x, F_3y)``, each component in ``[−f_max, f_max]``),
each spread over a boundary patch of radius ``patch_radius`` with a smooth bump so no
element inverts under the load (:func:`riskplan.deformable.patch_weights`). The forces are
dead loads (fixed direction in the world frame) scaled by ``params.force_scale``.

Physics: compressible neo-Hookean FEM (geometrically nonlinear, paper V-B), quasi-static:
each step solves ``f_int(u_{t+1}) = f_ext(u_t_control)`` by Newton's method with a line
search, warm-started from the previous displacement and load-stepped from the previous
load. Because the material is elastic and the loading quasi-static, the equilibrium
after a step depends on the current forces; the previous state enters through the warm
start and the load path (a different equilibrium branch would be reached only through a
buckling instability, which these loads do not reach).

Reduced state ``x = (p_target, P_boundary)`` (paper V-B): the target's position followed
by ``n_boundary`` boundary material points, ``(2 + 2 n_boundary,)``. Sensing: only the
boundary points, ``z = P_boundary + n``, ``n ~ N(0, σ² I)``. Failure: any part of the
deformed object touches the obstacle (boundary edges crossing the obstacle's, or one
inside the other).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from riskplan import geometry2d as geo
from riskplan._validation import as_array, as_generator, check_count
from riskplan.errors import ConvergenceError, ElementInversionError, InvalidInputError
from riskplan.scenarios.base import (
    FEMScenario,
    SimParams,
    SimState,
    apply_actuation_noise,
    check_control,
    frozen_array,
    gaussian_noise,
)

__all__ = ["ManipulationConfig", "ManipulationScenario", "ManipulationState"]


def _default_outline():
    return np.array([[0.0, 0.0], [0.7, 0.0], [1.0, 0.3], [1.0, 1.0], [0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class ManipulationConfig:
    """Geometry and constants of the manipulation scenario.

    ``outline (n, 2)``: the object (counter-clockwise); ``fixed_edge``: index ``i`` of the
    fixed edge ``outline[i] → outline[i+1]``; ``manipulators (3, 2)``: boundary points the
    forces act at; ``target (2,)``: internal target point; ``goal_center``/``goal_radius``:
    goal disk for the target (static, in the world frame); ``obstacle (k, 2)``: static
    polygon the object must not touch; ``n_boundary``: sensed boundary points, spread
    evenly by arc length over the free boundary; ``f_max``: force bound per component.
    """

    outline: np.ndarray = field(default_factory=_default_outline)
    fixed_edge: int = 1
    manipulators: np.ndarray = field(
        default_factory=lambda: np.array([[0.0, 0.3], [0.0, 0.8], [0.5, 1.0]])
    )
    target: tuple[float, float] = (0.45, 0.5)
    goal_center: tuple[float, float] = (0.33, 0.3)
    goal_radius: float = 0.04
    obstacle: np.ndarray = field(default_factory=lambda: geo.circle_polygon((-0.25, 0.2), 0.07, 20))
    patch_radius: float = 0.1
    n_boundary: int = 12
    f_max: float = 1.5
    sensing_std: float = 0.005
    plane: str = "strain"
    load_steps: int = 1

    def __post_init__(self):
        outline = as_array(self.outline, "outline", shape=(None, 2))
        if len(outline) < 3:
            raise InvalidInputError("outline: need at least 3 vertices")
        object.__setattr__(self, "outline", frozen_array(outline))
        if not 0 <= int(self.fixed_edge) < len(outline):
            raise InvalidInputError(
                f"fixed_edge: expected an index in [0, {len(outline) - 1}], got {self.fixed_edge}"
            )
        object.__setattr__(
            self,
            "manipulators",
            frozen_array(as_array(self.manipulators, "manipulators", shape=(None, 2))),
        )
        object.__setattr__(
            self, "obstacle", frozen_array(as_array(self.obstacle, "obstacle", shape=(None, 2)))
        )
        as_array(self.target, "target", shape=(2,))
        as_array(self.goal_center, "goal_center", shape=(2,))
        for name in ("goal_radius", "patch_radius", "f_max", "sensing_std"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v <= 0:
                raise InvalidInputError(f"{name}: must be finite and > 0, got {v!r}")
        if int(self.n_boundary) < 1:
            raise InvalidInputError(f"n_boundary: expected >= 1, got {self.n_boundary}")
        if geo.polygons_intersect(outline, self.obstacle):
            raise InvalidInputError("obstacle: overlaps the undeformed object")

    @property
    def fixed_segment(self) -> np.ndarray:
        i = int(self.fixed_edge)
        return np.stack([self.outline[i], self.outline[(i + 1) % len(self.outline)]])

    @property
    def goal_polygon(self) -> np.ndarray:
        return geo.circle_polygon(self.goal_center, self.goal_radius, 24)

    def boundary_points(self) -> np.ndarray:
        """``(n_boundary, 2)`` sensed points, evenly spaced by arc length along the free
        boundary (the outline without the fixed edge), away from its ends."""
        n = len(self.outline)
        i0 = (int(self.fixed_edge) + 1) % n
        chain = np.array(
            [self.outline[(i0 + k) % n] for k in range(n)]
        )  # free part: chain[0] .. chain[n-1]
        seg = np.diff(chain, axis=0)
        length = np.sqrt((seg**2).sum(1))
        cum = np.concatenate([[0.0], np.cumsum(length)])
        s = (np.arange(self.n_boundary) + 0.5) / self.n_boundary * cum[-1]
        k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
        t = (s - cum[k]) / length[k]
        return chain[k] + t[:, None] * seg[k]


@dataclass(frozen=True, eq=False)
class ManipulationState(SimState):
    """Full state: FEM displacement, step index, mesh size and the applied forces
    ``forces (3, 2)`` (after scaling and actuation noise) that it balances."""

    forces: np.ndarray = field(default_factory=lambda: np.zeros((3, 2)))

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "forces", frozen_array(self.forces))


def _boundary_loop(edges: np.ndarray) -> np.ndarray:
    """Node indices of the boundary cycle, in edge order (counter-clockwise)."""
    nxt = {int(a): int(b) for a, b in edges}
    start = int(edges[0, 0])
    loop = [start]
    while True:
        n = nxt[loop[-1]]
        if n == start:
            break
        loop.append(n)
        if len(loop) > len(edges):  # pragma: no cover - a valid mesh has one boundary cycle
            raise InvalidInputError("mesh: boundary is not a single cycle")
    return np.asarray(loop, dtype=np.int64)


def _nodes_on_segment(nodes: np.ndarray, seg: np.ndarray, tol: float) -> np.ndarray:
    a, b = seg
    ab = b - a
    t = np.clip(((nodes - a) @ ab) / (ab @ ab), 0.0, 1.0)
    d = np.sqrt(((nodes - (a + t[:, None] * ab)) ** 2).sum(1))
    return np.flatnonzero(d <= tol)


class _MeshData:
    """Cached per element count: mesh, fixed nodes, patch weights ``W (n_nodes, 3)``,
    interpolator for [target, sensed boundary points, manipulators], boundary loop."""

    def __init__(self, cfg: ManipulationConfig, n_elements: int):
        from riskplan.deformable import locate, mesh_polygon, patch_weights

        mesh = mesh_polygon(cfg.outline, n_elements, keep_points=cfg.manipulators)
        scale = float(np.ptp(cfg.outline, axis=0).max())
        self.mesh = mesh
        self.fixed = _nodes_on_segment(mesh.nodes, cfg.fixed_segment, 1e-9 * scale)
        W = np.stack(
            [patch_weights(mesh, c, cfg.patch_radius, on="boundary") for c in cfg.manipulators],
            axis=1,
        )
        W[self.fixed] = 0.0  # load on the support is taken by it
        self.W = W
        pts = np.concatenate(
            [
                np.asarray(cfg.target, dtype=np.float64)[None],
                cfg.boundary_points(),
                cfg.manipulators,
            ]
        )
        self.interp = locate(mesh, pts)
        self.loop = _boundary_loop(mesh.boundary_edges)
        nb = cfg.n_boundary
        self.target_index = 0
        self.boundary_slice = slice(1, 1 + nb)
        self.manipulator_slice = slice(1 + nb, 1 + nb + len(cfg.manipulators))
        self.outline_weights = _outline_weights(cfg, mesh.nodes[self.loop])


def _outline_weights(cfg: ManipulationConfig, ref: np.ndarray):
    """``(a, b, lam)`` for the boundary nodes ``ref (B, 2)`` (reference positions, loop
    order): each node moves with ``(1 − lam) d_a + lam d_b``, ``d_i`` the displacement of
    sensed point ``i``, interpolated by arc length between the two sensed points around it
    (:meth:`ManipulationConfig.boundary_points` spaces them by arc length); nodes before the
    first or after the last sensed point, the fixed edge's included, follow the nearer end
    point (an over-estimate of their motion: the fixed edge does not move)."""
    n = len(cfg.outline)
    i0 = (int(cfg.fixed_edge) + 1) % n
    k0 = int(np.argmin(((ref - cfg.outline[i0]) ** 2).sum(1)))
    order = np.roll(np.arange(len(ref)), -k0)
    r = ref[order]
    s = np.concatenate([[0.0], np.cumsum(np.sqrt((np.diff(r, axis=0) ** 2).sum(1)))])
    edges = np.roll(cfg.outline, -i0, axis=0)
    free_len = float(np.sqrt((np.diff(edges, axis=0) ** 2).sum(1)).sum())
    nb = int(cfg.n_boundary)
    sp = (np.arange(nb) + 0.5) / nb * free_len
    a = np.zeros(len(ref), dtype=np.int64)
    b = np.zeros(len(ref), dtype=np.int64)
    lam = np.zeros(len(ref))
    total = s[-1] + float(np.sqrt(((r[-1] - r[0]) ** 2).sum()))
    for q, sq in zip(order, s):
        if nb > 1 and sp[0] <= sq <= sp[-1]:
            k = min(int(np.searchsorted(sp, sq, side="right")) - 1, nb - 2)
            a[q], b[q], lam[q] = k, k + 1, (sq - sp[k]) / (sp[k + 1] - sp[k])
        else:
            end = nb - 1 if sp[-1] < sq <= 0.5 * (free_len + total) else 0
            a[q] = b[q] = end
    return a, b, lam


class ManipulationScenario(FEMScenario):
    """The internal-point manipulation scenario as a
    :class:`~riskplan.scenarios.base.Simulator`.

    Dimensions: controls q = 2 × (number of manipulators) = 6; reduced state
    p = 2 + 2 n_boundary (26 by default); measurements 2 n_boundary. ``cache_size``: FEM
    models kept (one per distinct ``(E, ν, n_elements)``; the plan selection cycles through
    the nominal model and its 16 parameter draws, which a cache of 16 would evict one by one).
    """

    name = "manipulation"
    state_type = ManipulationState
    #: Quasi-static: each step solves for the equilibrium under the current forces from any
    #: start (tested in tests/scenarios/test_manipulation.py), so a deviation of the state is
    #: forgotten by the next step and the exact ``A_t`` is 0 — also in the directions the
    #: linearisation's control perturbations do not excite (``riskplan.control.linearize``).
    a_prior = "zero"

    def __init__(
        self, config: ManipulationConfig | None = None, distribution=None, cache_size: int = 32
    ):
        super().__init__(config or ManipulationConfig(), distribution, cache_size)
        cfg = self.config
        m = len(cfg.manipulators)
        self.control_dim = 2 * m
        self.state_dim = 2 + 2 * cfg.n_boundary
        self.obs_dim = 2 * cfg.n_boundary
        b = np.tile(np.array([[-cfg.f_max, cfg.f_max]]), (self.control_dim, 1))
        b.setflags(write=False)
        self._bounds = b
        H = np.zeros((self.obs_dim, self.state_dim))
        H[:, 2:] = np.eye(self.obs_dim)
        H.setflags(write=False)
        self.observation_matrix = H
        cov = cfg.sensing_std**2 * np.eye(self.obs_dim)
        cov.setflags(write=False)
        self.sensing_cov = cov
        # where the 2-D points of x are (LQG-MP, riskplan.control.lqgmp): collision is
        # judged on the deformed outline moving with the sensed boundary points
        # (collision_outline), the goal on the target
        self.collision_point_indices = tuple((2 + 2 * i, 3 + 2 * i) for i in range(cfg.n_boundary))
        self.goal_point_indices = (0, 1)

    @property
    def state_scale(self) -> np.ndarray:
        """``(p,)`` acceptable deviation of each reduced-state component, the scale of the
        LQR's default Bryson weights (:func:`riskplan.control.lqg_controller`): the goal
        radius for the target (placing it is the objective), four goal radii for each
        boundary point (the outline matters only through obstacle contact, so its twelve
        points together weigh less than the target)."""
        r = self.config.goal_radius
        return np.concatenate([[r, r], np.full(self.state_dim - 2, 4.0 * r)])

    # ---- protocol ------------------------------------------------------------------
    @property
    def control_bounds(self) -> np.ndarray:
        """``(6, 2)``: ``[−f_max, f_max]`` for every force component."""
        return self._bounds

    def actuation_cov(self) -> tuple:
        """Default actuation noise for this scenario: ``(0.1 f_max)²`` per component."""
        s2 = (0.1 * self.config.f_max) ** 2
        return tuple(
            tuple(s2 if i == j else 0.0 for j in range(self.control_dim))
            for i in range(self.control_dim)
        )

    def _make_mesh_data(self, n_elements: int) -> _MeshData:
        return _MeshData(self.config, n_elements)

    def _make_model(self, params: SimParams):
        """The neo-Hookean model of the object for ``params``."""
        from riskplan.deformable import Material, NeoHookeanModel

        d = self.mesh_data(params.n_elements)
        material = Material(params.youngs_modulus, params.poissons_ratio, plane=self.config.plane)
        return NeoHookeanModel(d.mesh, material, d.fixed)

    def initial_state(self, params: SimParams | None = None) -> ManipulationState:
        """Undeformed object, no forces, ``t = 0``."""
        params = params or self.nominal_params
        d = self.mesh_data(params.n_elements)
        return ManipulationState(
            t=0,
            displacement=np.zeros((d.mesh.n_nodes, 2)),
            n_elements=params.n_elements,
            forces=np.zeros((len(self.config.manipulators), 2)),
        )

    def transfer_state(self, state: ManipulationState, params: SimParams) -> ManipulationState:
        """``state`` as a start on the mesh of ``params`` (another ``n_elements``).

        Exact for this quasi-static scenario: the next step's equilibrium does not depend on
        the state it starts from (tested), so the undeformed body of the other mesh at the
        same step index is as good a start as any. :func:`riskplan.control.linearize` uses it
        to run the mesh-size draws of ``M_t`` on their own meshes.
        """
        out = self.initial_state(params)
        return ManipulationState(
            t=state.t,
            displacement=out.displacement,
            n_elements=out.n_elements,
            forces=out.forces,
        )

    def nodal_forces(self, state: ManipulationState) -> np.ndarray:
        """Consistent nodal forces ``(n_nodes, 2)`` of the forces applied in ``state``
        (what ``state.displacement`` balances)."""
        return self.mesh_data(state.n_elements).W @ state.forces

    def step(
        self, state: ManipulationState, control, params: SimParams | None = None
    ) -> ManipulationState:
        """``y_{t+1} = g(y_t, u_t, s)`` (paper eq. 1): quasi-static neo-Hookean equilibrium
        under the manipulator forces ``control (6,)`` (× ``force_scale``, plus actuation
        noise if ``params`` has some), warm-started from ``state``.

        Raises :class:`InvalidInputError` for a control outside the bounds or NaN,
        :class:`ElementInversionError` / :class:`ConvergenceError` (message says which
        step, which forces, which elements / what residual) if the solve fails.
        """
        return self._step(state, control, params, None)

    def step_near(
        self,
        state: ManipulationState,
        control,
        params: SimParams | None = None,
        near: ManipulationState | None = None,
    ) -> ManipulationState:
        """:meth:`step`, with the Newton solve started from ``near``'s displacement (a state
        expected close to the result, e.g. the nominal plan's next state when
        :func:`riskplan.control.linearize` perturbs a control), falling back to the start
        from ``state`` if that solve fails.

        The equilibrium depends only on the applied forces (module docstring), so the
        result equals :meth:`step`'s up to the solver tolerance (``rtol = 1e-9`` of the
        load); a start near the answer only saves Newton iterations. ``near=None`` (or on
        another mesh) is :meth:`step`.
        """
        params = params or self.nominal_params
        if near is None or near.n_elements != params.n_elements:
            return self._step(state, control, params, None)
        try:
            return self._step(state, control, params, near.displacement)
        except (ConvergenceError, ElementInversionError):
            return self._step(state, control, params, None)

    def _step(self, state, control, params, u0) -> ManipulationState:
        params = params or self.nominal_params
        self._check_state(state, params)
        u = check_control(control, self._bounds)
        u = apply_actuation_noise(u, params, state.t, self._bounds)
        forces = params.force_scale * u.reshape(-1, 2)
        f = self.mesh_data(params.n_elements).W @ forces
        try:
            disp, _info = self.model(params).solve_with_info(
                f,
                state.displacement if u0 is None else u0,
                load_steps=self.config.load_steps,
            )
        except ElementInversionError as exc:
            raise ElementInversionError(
                f"manipulation step t={state.t} -> {state.t + 1} with forces {forces.round(4).tolist()}: {exc}",
                elements=exc.elements,
                min_jacobian=exc.min_jacobian,
            ) from exc
        except ConvergenceError as exc:
            raise ConvergenceError(
                f"manipulation step t={state.t} -> {state.t + 1} with forces {forces.round(4).tolist()}: {exc}",
                residual=exc.residual,
                iterations=exc.iterations,
            ) from exc
        if not np.all(np.isfinite(disp)):  # pragma: no cover - the solver raises first
            raise ConvergenceError(f"manipulation step t={state.t}: non-finite displacement")
        return ManipulationState(
            t=state.t + 1, displacement=disp, n_elements=state.n_elements, forces=forces
        )

    def reduced(self, state: ManipulationState) -> np.ndarray:
        """``x = (p_target, P_boundary)`` ``(2 + 2 n_boundary,)`` (paper V-B)."""
        return self._points(state)[: 1 + self.config.n_boundary].reshape(-1)

    def observe(self, x, noise=None, rng=None) -> np.ndarray:
        """``z = H x + n`` (paper eq. 3): the boundary points only."""
        x = as_array(x, "x", shape=(self.state_dim,))
        return self.observation_matrix @ x + gaussian_noise(
            self.sensing_cov, noise, rng, self.obs_dim
        )

    # ---- geometry of a state ------------------------------------------------------------
    def target(self, state) -> np.ndarray:
        """Current target position ``(2,)``."""
        return self._points(state)[0]

    def boundary_points(self, state) -> np.ndarray:
        """Current sensed boundary points ``(n_boundary, 2)``."""
        return self._points(state)[self._data(state).boundary_slice]

    def manipulator_positions(self, state) -> np.ndarray:
        """Current manipulator contact points ``(3, 2)``."""
        return self._points(state)[self._data(state).manipulator_slice]

    def outline(self, state) -> np.ndarray:
        """The deformed boundary polygon ``(B, 2)`` (all boundary nodes, CCW)."""
        d = self._data(state)
        return d.mesh.nodes[d.loop] + state.displacement[d.loop]

    def obstacles(self, state=None) -> list[np.ndarray]:
        """The static obstacle (a list with one polygon)."""
        return [self.config.obstacle]

    def goal(self, state=None) -> np.ndarray:
        """The static goal polygon ``(24, 2)``."""
        return self.config.goal_polygon

    def collision_outline(self, state):
        """The body LQG-MP checks against the obstacle (:func:`riskplan.control.lqgmp.body_points`):
        ``(outline (B, 2), a (B,), b (B,), lam (B,))``, the deformed boundary nodes of
        ``state`` (a closed polygon), each moving with the deviations of the sensed points
        ``a`` and ``b`` around it, interpolated by arc length. The 12 sensed points alone are
        ~0.28 apart, wider than the obstacle (0.14): an outline wrapped round the obstacle
        would pass between them unseen."""
        a, b, lam = self._data(state).outline_weights
        return self.outline(state), a, b, lam

    def in_collision(self, state) -> bool:
        """The deformed object touches the obstacle."""
        return geo.polygons_intersect(self.outline(state), self.config.obstacle)

    def in_goal(self, state) -> bool:
        """The target lies in the goal disk."""
        return self.goal_distance(state) <= self.config.goal_radius

    def goal_distance(self, state) -> float:
        """Distance from the target to the goal centre."""
        return float(np.linalg.norm(self.target(state) - np.asarray(self.config.goal_center)))

    def path(self, states) -> np.ndarray:
        """Target positions ``(T, 2)`` along a list of states."""
        return np.array([self.target(s) for s in states])

    def random_controls(self, n_steps: int, seed=None) -> np.ndarray:
        """``(n_steps, 6)`` smooth random forces: a random walk clipped to ``±0.6 f_max``."""
        n_steps = check_count(n_steps, "n_steps")
        gen = as_generator(seed)
        steps = gen.normal(0.0, 0.15 * self.config.f_max, (n_steps, self.control_dim))
        return np.clip(np.cumsum(steps, axis=0), -0.6 * self.config.f_max, 0.6 * self.config.f_max)
