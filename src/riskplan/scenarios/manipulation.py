"""Scenario 2 of the deformable-planning paper (Patil, van den Berg & Alterovitz, RSS 2011,
section V-B): external manipulation of a planar deformable object to move an internal
target point into a goal region while the object avoids a static obstacle.

Object: a unit square with its bottom-right corner cut off; the cut edge (the
"bottom-right edge") is fixed. Three manipulators hold the object at boundary material
points and push/pull it with force vectors ``F_k`` (``F = (F_1x, F_1y, F_2x, F_2y, F_3x,
F_3y)``), each spread over a boundary patch of radius ``patch_radius`` with a smooth bump
so no element inverts under the load (:func:`riskplan.deformable.patch_weights`). The
forces are dead loads (fixed direction in the world frame).

Controls are force *increments* and the applied forces are part of the state (the
paper's simulator state y_t holds "deformations, dynamics parameters, friction states",
§III): the control ``Δu (6,)``, each component in ``[−df_max, df_max]``, changes the
applied forces by

    F_{t+1} = clip(F_t + s_f (Δu_t + w_t), −f_max, f_max)

(``s_f = params.force_scale``, an actuator gain; ``w_t`` the actuation noise; the clip is
the manipulators' saturation, so the force bound ``f_max`` holds whatever the controls).
The object then settles in the quasi-static equilibrium under ``F_{t+1}``.

Why increments (and not a damped dynamic FEM): with absolute forces as controls every step
is a memoryless equilibrium (``x_{t+1}`` a function of ``u_t`` only), so the linearisation's
``A_t`` is 0, the LQR gains are 0 and LQG executes the plan open loop. Holding the forces
in the state gives the deviation model memory with the exact structure

    x̄_{t+1} = A_t x̄_t + B_t ū_t,   A_t = [[0, J_{t+1}], [0, I]],   B_t = s_f [[J_{t+1}], [I]]

(``J_{t+1} = ∂P/∂F`` at the new equilibrium, :meth:`ManipulationScenario.force_jacobian`):
a force deviation persists until the controller removes it, and the positions follow the
forces. A dynamic FEM would add memory through velocities as well, but the paper's object
is manipulated slowly (no inertia in its model of §V-B), its time step and damping would
be new parameters the paper does not give, and each step would cost several implicit
solves; the increments need neither.

Physics: compressible neo-Hookean FEM (geometrically nonlinear, paper V-B), quasi-static:
each step solves ``f_int(u_{t+1}) = W F_{t+1}`` by Newton's method with a line search,
warm-started from the previous displacement and load-stepped from the previous load.
Because the material is elastic and the loading quasi-static, the equilibrium depends on
the applied forces only; the previous state enters through the warm start and the load
path (a different equilibrium branch would be reached only through a buckling
instability, which these loads do not reach).

Reduced state ``x = (p_target, P_boundary, F)`` (paper V-B, plus the applied forces): the
target's position, ``n_boundary`` boundary material points and the six force components,
``(2 + 2 n_boundary + 6,)``. Sensing: only the boundary points, ``z = P_boundary + n``,
``n ~ N(0, σ² I)`` (the forces are estimated by the filter). Failure: any part of the
deformed object touches the obstacle (boundary edges crossing the obstacle's, or one
inside the other).
"""

from __future__ import annotations

import math
from collections import OrderedDict
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
from riskplan.scenarios.manipulation_mesh import MeshData
from riskplan.scenarios.space import BoxSpace
from riskplan.scenarios.values import check_material

__all__ = ["ManipulationConfig", "ManipulationScenario", "ManipulationState"]

#: results of ``ManipulationScenario.step_near`` under parameters without actuation noise,
#: keyed by the scenario's configuration and every argument (least recently used dropped).
#: The step is a pure function of them, so a hit changes no result; it spares the
#: linearisation's control-perturbation runs for ``B_t``, which are the same under every
#: uncertainty case of a candidate (Fig. 6 linearises one candidate under five cases).
_STEP_MEMO: OrderedDict = OrderedDict()
_STEP_MEMO_SIZE = 512


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
    evenly by arc length over the free boundary; ``f_max``: bound of each applied force
    component (the manipulators saturate there); ``df_max``: bound of each force
    increment per step (the control), a quarter of ``f_max`` so that swinging a force from
    zero to its bound takes at least four steps (the rate limit the RRT used when controls
    were absolute forces: a quasi-static step jumps to the new equilibrium, and a larger
    jump would skip configurations the collision check never sees);
    ``sensing_std``: standard deviation of each boundary-point measurement, by default
    ``0.005 · (largest extent of the outline)`` (0.005 on the paper's unit object);
    ``actuation_std``: standard deviation of each force increment's actuation noise, by
    default ``0.1 df_max`` (:meth:`ManipulationScenario.actuation_cov`);
    ``youngs_modulus``/``poissons_ratio``: the nominal material.
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
    df_max: float = 0.375
    sensing_std: float | None = None
    plane: str = "strain"
    load_steps: int = 1
    actuation_std: float | None = None
    youngs_modulus: float = 50.0
    poissons_ratio: float = 0.4

    def __post_init__(self):
        outline = as_array(self.outline, "outline", shape=(None, 2))
        if len(outline) < 3:
            raise InvalidInputError("outline: need at least 3 vertices")
        if self.sensing_std is None:
            extent = float(np.max(outline.max(0) - outline.min(0)))
            object.__setattr__(self, "sensing_std", 0.005 * extent)
        if self.actuation_std is not None:
            a = float(self.actuation_std)
            if not (math.isfinite(a) and a >= 0.0):
                raise InvalidInputError(f"actuation_std: must be finite and >= 0, got {a!r}")
        check_material(self.youngs_modulus, self.poissons_ratio)
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
        for name in ("goal_radius", "patch_radius", "f_max", "df_max", "sensing_std"):
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
    ``forces (3, 2)`` (the sum of the scaled, noisy, saturated increments so far) that the
    displacement balances; the forces are part of the reduced state too."""

    forces: np.ndarray = field(default_factory=lambda: np.zeros((3, 2)))

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "forces", frozen_array(self.forces))


class ManipulationScenario(FEMScenario):
    """The internal-point manipulation scenario as a
    :class:`~riskplan.scenarios.base.Simulator`.

    Dimensions: controls q = 2 × (number of manipulators) = 6 force increments; reduced
    state p = 2 + 2 n_boundary + q (32 by default: target, boundary points, applied
    forces); measurements 2 n_boundary. ``cache_size``: FEM models kept (one per distinct
    ``(E, ν, n_elements)``; the plan selection cycles through the nominal model and its 16
    parameter draws, which a cache of 16 would evict one by one).
    """

    name = "manipulation"
    state_type = ManipulationState

    def __init__(
        self, config: ManipulationConfig | None = None, distribution=None, cache_size: int = 32
    ):
        super().__init__(config or ManipulationConfig(), distribution, cache_size)
        cfg = self.config
        m = len(cfg.manipulators)
        self.control_dim = 2 * m
        self.n_points = 1 + cfg.n_boundary
        self.state_dim = 2 * self.n_points + self.control_dim
        self.obs_dim = 2 * cfg.n_boundary
        b = np.tile(np.array([[-cfg.df_max, cfg.df_max]]), (self.control_dim, 1))
        b.setflags(write=False)
        self._bounds = b
        H = np.zeros((self.obs_dim, self.state_dim))
        H[:, 2 : 2 * self.n_points] = np.eye(self.obs_dim)
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
        #: slice of x holding the applied forces
        self.force_slice = slice(2 * self.n_points, self.state_dim)

    @property
    def state_scale(self) -> np.ndarray:
        """``(p,)`` acceptable deviation of each reduced-state component, the scale of the
        LQR's default Bryson weights (:func:`riskplan.control.lqg_controller`): the goal
        radius for the target (placing it is the objective), four goal radii for each
        boundary point (the outline matters only through obstacle contact, so its twelve
        points together weigh less than the target), and ``f_max`` for each applied force
        (a force matters only through the positions it produces, which are weighted
        already; the whole force range keeps the controller from pulling a force back to
        the plan's against the target)."""
        r = self.config.goal_radius
        return np.concatenate(
            [
                [r, r],
                np.full(2 * self.config.n_boundary, 4.0 * r),
                np.full(self.control_dim, self.config.f_max),
            ]
        )

    # ---- protocol ------------------------------------------------------------------
    @property
    def control_bounds(self) -> np.ndarray:
        """``(6, 2)``: ``[−df_max, df_max]`` for every force increment."""
        return self._bounds

    def planning_space(self) -> BoxSpace:
        """The RRT's :class:`~riskplan.scenarios.space.BoxSpace`: the object's bounding box
        for the target position, which alone is measured (the boundary points follow it),
        and one step of force increments per extension (the increment bound is the rate
        limit: larger force jumps would skip configurations that the collision check never
        sees)."""
        cfg = self.config
        p = self.state_dim
        low, high, w, goal = np.zeros(p), np.ones(p), np.zeros(p), np.zeros(p)
        low[:2], high[:2], w[:2], goal[:2] = (
            cfg.outline.min(0),
            cfg.outline.max(0),
            1.0,
            cfg.goal_center,
        )
        return BoxSpace(low=low, high=high, weights=w, periodic=np.zeros(p, dtype=bool), goal=goal)

    def actuation_cov(self) -> tuple:
        """Default actuation noise for this scenario: ``(0.1 df_max)²`` per increment
        component (10 % of the half-range of each control, the rule of
        :mod:`riskplan.scenarios.uncertainty`). It is added to every increment, so the
        applied forces carry a random walk of it. ``config.actuation_std``, when set,
        replaces ``0.1 df_max``."""
        a = self.config.actuation_std
        s2 = (0.1 * self.config.df_max) ** 2 if a is None else float(a) ** 2
        return tuple(
            tuple(s2 if i == j else 0.0 for j in range(self.control_dim))
            for i in range(self.control_dim)
        )

    def a_prior(self, state: ManipulationState, params: SimParams | None = None) -> np.ndarray:
        """``(p, p)`` the exact structure of ``A_t`` at the new state ``state = y*_{t+1}``
        (module docstring), the prior :func:`riskplan.control.linearize` corrects with its
        control-perturbation runs:

            A = [[0, J], [0, I]],   J = ∂(p_target, P_boundary)/∂F  (:meth:`force_jacobian`)

        A deviation of the positions alone is forgotten (the next equilibrium depends on
        the forces only); a deviation of the forces persists and moves the positions by
        ``J``. Saturated forces are not special-cased (as the linear model ignores control
        clipping)."""
        q, n = self.control_dim, 2 * self.n_points
        A = np.zeros((self.state_dim, self.state_dim))
        A[:n, n:] = self.force_jacobian(state, params)
        A[n:, n:] = np.eye(q)
        return A

    def force_jacobian(self, state: ManipulationState, params: SimParams | None = None):
        """``J (2 + 2 n_boundary, 6)``: derivative of the target and boundary positions with
        respect to the applied forces at the equilibrium ``state``, from the tangent
        stiffness ``K_T`` of the neo-Hookean model (implicit function theorem on
        ``f_int(u) = W F``):

            ∂u/∂F = K_T(u)⁻¹ W,   J = Π ∂u/∂F

        with ``W`` the patch weights and ``Π`` the interpolation at the material points."""
        from scipy.sparse.linalg import splu

        params = params or self.nominal_params
        self._check_state(state, params)
        d = self.mesh_data(params.n_elements)
        model = self.model(params)
        K = model.tangent(state.displacement).tocsc()
        n_nodes = d.mesh.n_nodes
        q = self.control_dim
        # nodal force of force component (k, c): W[:, k] on the c-components of the nodes
        rhs = np.zeros((2 * n_nodes, q))
        for k in range(q // 2):
            for c in range(2):
                rhs[c::2, 2 * k + c] = d.W[:, k]
        free = model.free_dofs
        du = np.zeros((2 * n_nodes, q))
        du[free] = splu(K).solve(np.ascontiguousarray(rhs[free]))
        du = du.reshape(n_nodes, 2, q)
        interp = d.interp
        # positions of [target, boundary points] (the first n_points interpolated points)
        np_ = self.n_points
        w = interp.weights[:np_]  # (P, 3)
        idx = interp.node_index[:np_]  # (P, 3)
        J = np.einsum("pa,pacq->pcq", w, du[idx])  # (P, 2, q)
        return J.reshape(2 * np_, q)

    def _make_mesh_data(self, n_elements: int) -> MeshData:
        return MeshData(self.config, n_elements)

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

    #: load steps of a solve from the undeformed body to the full forces when one step
    #: fails (transfer_state)
    TRANSFER_LOAD_STEPS = 4

    def transfer_state(self, state: ManipulationState, params: SimParams) -> ManipulationState:
        """``state`` as a start on the mesh (and material) of ``params``: the same step index
        and applied forces, in equilibrium on that mesh.

        Exact: the equilibrium depends only on the applied forces (module docstring), so
        the body of the other mesh under the same forces is the state an execution on that
        mesh would be in. Solved from the undeformed body in one load step, or in
        :attr:`TRANSFER_LOAD_STEPS` if that fails. :func:`riskplan.control.linearize` uses
        it to run the mesh-size draws of ``M_t`` on their own meshes.
        """
        out = self.initial_state(params)
        forces = np.asarray(state.forces, dtype=np.float64)
        disp = out.displacement
        if np.any(forces):
            try:
                disp = self._solve(forces, disp, params, state.t, 1)
            except (ConvergenceError, ElementInversionError):
                disp = self._solve(forces, disp, params, state.t, self.TRANSFER_LOAD_STEPS)
        return ManipulationState(
            t=state.t, displacement=disp, n_elements=out.n_elements, forces=forces
        )

    def nodal_forces(self, state: ManipulationState) -> np.ndarray:
        """Consistent nodal forces ``(n_nodes, 2)`` of the forces applied in ``state``
        (what ``state.displacement`` balances)."""
        return self.mesh_data(state.n_elements).W @ state.forces

    def step(
        self, state: ManipulationState, control, params: SimParams | None = None
    ) -> ManipulationState:
        """``y_{t+1} = g(y_t, u_t, s)`` (paper eq. 1): the applied forces change by the
        increments ``control (6,)`` (× ``force_scale``, plus actuation noise if ``params``
        has some, saturated at ``±f_max``), then the quasi-static neo-Hookean equilibrium
        under the new forces, warm-started from ``state``.

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
        key = None
        if params.actuation_cov is None:
            key = self._memo_key(state, control, params, near)
            hit = _STEP_MEMO.get(key)
            if hit is not None:
                _STEP_MEMO.move_to_end(key)
                return hit
        if near is None or near.n_elements != params.n_elements:
            out = self._step(state, control, params, None)
        else:
            try:
                out = self._step(state, control, params, near.displacement)
            except (ConvergenceError, ElementInversionError):
                out = self._step(state, control, params, None)
        if key is not None:
            _STEP_MEMO[key] = out
            if len(_STEP_MEMO) > _STEP_MEMO_SIZE:
                _STEP_MEMO.popitem(last=False)
        return out

    def _memo_key(self, state, control, params, near) -> tuple:
        """Everything ``step_near``'s result depends on (``_STEP_MEMO``)."""

        def arr(a):
            a = np.asarray(a, dtype=np.float64)
            return a.shape, a.tobytes()

        return (
            self._content_key(),
            params,
            state.t,
            state.n_elements,
            arr(state.displacement),
            arr(state.forces),
            arr(control),
            None if near is None else (near.n_elements, arr(near.displacement)),
        )

    def next_forces(self, state: ManipulationState, control, params: SimParams) -> np.ndarray:
        """``(3, 2)`` the forces applied after ``control`` from ``state`` (module docstring):
        ``clip(F_t + s_f (Δu + w_t), −f_max, f_max)``; ``control`` is trusted (checked by
        :meth:`step`)."""
        u = apply_actuation_noise(control, params, state.t, self._bounds)
        f_max = self.config.f_max
        return np.clip(state.forces + params.force_scale * u.reshape(-1, 2), -f_max, f_max)

    def _solve(self, forces, u0, params, t, load_steps) -> np.ndarray:
        f = self.mesh_data(params.n_elements).W @ forces
        try:
            disp, _info = self.model(params).solve_with_info(f, u0, load_steps=load_steps)
        except ElementInversionError as exc:
            raise ElementInversionError(
                f"manipulation step t={t} -> {t + 1} with forces {forces.round(4).tolist()}: {exc}",
                elements=exc.elements,
                min_jacobian=exc.min_jacobian,
            ) from exc
        except ConvergenceError as exc:
            raise ConvergenceError(
                f"manipulation step t={t} -> {t + 1} with forces {forces.round(4).tolist()}: {exc}",
                residual=exc.residual,
                iterations=exc.iterations,
            ) from exc
        if not np.all(np.isfinite(disp)):  # pragma: no cover - the solver raises first
            raise ConvergenceError(f"manipulation step t={t}: non-finite displacement")
        return disp

    def _step(self, state, control, params, u0) -> ManipulationState:
        params = params or self.nominal_params
        self._check_state(state, params)
        u = check_control(control, self._bounds)
        forces = self.next_forces(state, u, params)
        disp = self._solve(
            forces,
            state.displacement if u0 is None else u0,
            params,
            state.t,
            self.config.load_steps,
        )
        return ManipulationState(
            t=state.t + 1, displacement=disp, n_elements=state.n_elements, forces=forces
        )

    def reduced(self, state: ManipulationState) -> np.ndarray:
        """``x = (p_target, P_boundary, F)`` ``(2 + 2 n_boundary + 6,)`` (paper V-B, plus the
        applied forces)."""
        pts = self._points(state)[: self.n_points].reshape(-1)
        return np.concatenate([pts, np.asarray(state.forces, dtype=np.float64).reshape(-1)])

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
        """``(n_steps, 6)`` random force increments whose applied forces (their cumulative
        sum) are a random walk with steps ``N(0, (0.15 f_max)²)`` clipped to ``±df_max``,
        the walk kept within ``±0.6 f_max``."""
        n_steps = check_count(n_steps, "n_steps")
        gen = as_generator(seed)
        cfg = self.config
        steps = np.clip(
            gen.normal(0.0, 0.15 * cfg.f_max, (n_steps, self.control_dim)), -cfg.df_max, cfg.df_max
        )
        walk = np.clip(np.cumsum(steps, axis=0), -0.6 * cfg.f_max, 0.6 * cfg.f_max)
        du = np.diff(walk, axis=0, prepend=np.zeros((1, self.control_dim)))
        return np.clip(du, -cfg.df_max, cfg.df_max)  # rounding of the difference
