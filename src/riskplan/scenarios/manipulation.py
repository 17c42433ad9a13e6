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

import numpy as np

from riskplan._validation import as_array, as_generator, check_count
from riskplan.scenarios import manipulation_geometry, manipulation_step
from riskplan.scenarios.base import (
    FEMScenario,
    SimParams,
    gaussian_noise,
)
from riskplan.scenarios.manipulation_config import ManipulationConfig, ManipulationState
from riskplan.scenarios.manipulation_mesh import MeshData
from riskplan.scenarios.space import BoxSpace

# the configuration and state live in manipulation_config; this module hands them on
__all__ = ["ManipulationConfig", "ManipulationScenario", "ManipulationState"]


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
        sees).

        Returns
        -------
        BoxSpace
            Over the ``p``-dimensional reduced state: the outline's box for the target
            ``x[:2]`` (weight 1), unit bounds and weight 0 for the other components, the
            goal centre as the goal sample.
        """
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
        r"""Default actuation noise for this scenario: ``(0.1 df_max)²`` per increment
        component (10 % of the half-range of each control, the rule of
        :mod:`riskplan.scenarios.uncertainty`). It is added to every increment, so the
        applied forces carry a random walk of it. ``config.actuation_std``, when set,
        replaces ``0.1 df_max``:

        .. math::

            W = \sigma_a^2 I_q, \qquad \sigma_a = 0.1\, \Delta f_{\max}

        Returns
        -------
        tuple of tuple of float, shape (q, q)
            ``W`` in force units², as :class:`SimParams` ``actuation_cov`` holds it.
        """
        a = self.config.actuation_std
        s2 = (0.1 * self.config.df_max) ** 2 if a is None else float(a) ** 2
        return tuple(
            tuple(s2 if i == j else 0.0 for j in range(self.control_dim))
            for i in range(self.control_dim)
        )

    def a_prior(self, state: ManipulationState, params: SimParams | None = None) -> np.ndarray:
        r"""``(p, p)`` the exact structure of ``A_t`` at the new state ``state = y*_{t+1}``
        (module docstring), the prior :func:`riskplan.control.linearize` corrects with its
        control-perturbation runs:

        .. math::

            A = \begin{pmatrix} 0 & J \\ 0 & I_q \end{pmatrix}, \qquad
            J = \frac{\partial (p_{\mathrm{target}}, P_{\mathrm{boundary}})}{\partial F}

        (:meth:`force_jacobian`). A deviation of the positions alone is forgotten (the next
        equilibrium depends on the forces only); a deviation of the forces persists and
        moves the positions by ``J``. Saturated forces are not special-cased (as the linear
        model ignores control clipping).

        Parameters
        ----------
        state : ManipulationState
            The plan's next state ``y*_{t+1}`` (an equilibrium).
        params : SimParams, optional
            ``s`` (default: the nominal parameters).

        Returns
        -------
        numpy.ndarray, shape (p, p)
        """
        q, n = self.control_dim, 2 * self.n_points
        A = np.zeros((self.state_dim, self.state_dim))
        A[:n, n:] = self.force_jacobian(state, params)
        A[n:, n:] = np.eye(q)
        return A

    def force_jacobian(self, state: ManipulationState, params: SimParams | None = None):
        r"""``J (2 + 2 n_boundary, 6)``: derivative of the target and boundary positions with
        respect to the applied forces at the equilibrium ``state``, from the tangent
        stiffness ``K_T`` of the neo-Hookean model (implicit function theorem on
        ``f_int(u) = W F``):

        .. math::

            \frac{\partial u}{\partial F} = K_T(u)^{-1} W, \qquad
            J = \Pi \frac{\partial u}{\partial F}

        with ``W`` the patch weights and ``Π`` the interpolation at the material points.

        Parameters
        ----------
        state : ManipulationState
            An equilibrium on the mesh of ``params``.
        params : SimParams, optional
            ``s`` (default: the nominal parameters).

        Returns
        -------
        numpy.ndarray, shape (2 + 2 n_boundary, q)
            Rows: target then boundary points, ``(x, y)`` each; columns: the force
            components ``(F_1x, F_1y, ...)``; lengths per force unit.
        """
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
        """The start state ``y_0``: undeformed object, no forces, ``t = 0``.

        Parameters
        ----------
        params : SimParams, optional
            Default: the nominal parameters (their ``n_elements`` picks the mesh).

        Returns
        -------
        ManipulationState
        """
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

    def nodal_forces(self, state: ManipulationState) -> np.ndarray:
        """Consistent nodal forces of the forces applied in ``state`` (what
        ``state.displacement`` balances): ``f = W F`` with the patch weights ``W``.

        Parameters
        ----------
        state : ManipulationState

        Returns
        -------
        numpy.ndarray, shape (n_nodes, 2)
        """
        return self.mesh_data(state.n_elements).W @ state.forces

    # the step (module docstring): functions of manipulation_step, bound here
    transfer_state = manipulation_step.transfer_state
    step = manipulation_step.step
    step_near = manipulation_step.step_near
    next_forces = manipulation_step.next_forces
    _memo_key = manipulation_step._memo_key
    _solve = manipulation_step._solve
    _step = manipulation_step._step

    def reduced(self, state: ManipulationState) -> np.ndarray:
        """The reduced state ``x = (p_target, P_boundary, F)`` (paper V-B, plus the applied
        forces).

        Parameters
        ----------
        state : ManipulationState

        Returns
        -------
        numpy.ndarray, shape (2 + 2 n_boundary + q,)
            Target ``(x, y)``, the boundary points' ``(x, y)``, then the force components.
        """
        pts = self._points(state)[: self.n_points].reshape(-1)
        return np.concatenate([pts, np.asarray(state.forces, dtype=np.float64).reshape(-1)])

    def observe(self, x, noise=None, rng=None) -> np.ndarray:
        """``z = H x + n`` (paper eq. 3): the boundary points only.

        Parameters
        ----------
        x : array_like, shape (p,)
            Reduced state.
        noise : array_like, shape (2 n_boundary,), optional
            ``n`` given explicitly; else drawn from ``N(0, σ² I)`` with ``rng``.
        rng : int, numpy.random.Generator or None
            Draws ``n``; zero noise if neither ``noise`` nor ``rng`` is given.

        Returns
        -------
        numpy.ndarray, shape (2 n_boundary,)
        """
        x = as_array(x, "x", shape=(self.state_dim,))
        return self.observation_matrix @ x + gaussian_noise(
            self.sensing_cov, noise, rng, self.obs_dim
        )

    # the geometry of a state: functions of manipulation_geometry, bound here
    target = manipulation_geometry.target
    boundary_points = manipulation_geometry.boundary_points
    manipulator_positions = manipulation_geometry.manipulator_positions
    outline = manipulation_geometry.outline
    obstacles = manipulation_geometry.obstacles
    goal = manipulation_geometry.goal
    collision_outline = manipulation_geometry.collision_outline
    in_collision = manipulation_geometry.in_collision
    in_goal = manipulation_geometry.in_goal
    goal_distance = manipulation_geometry.goal_distance
    path = manipulation_geometry.path

    def random_controls(self, n_steps: int, seed=None) -> np.ndarray:
        """``(n_steps, 6)`` random force increments whose applied forces (their cumulative
        sum) are a random walk with steps ``N(0, (0.15 f_max)²)`` clipped to ``±df_max``,
        the walk kept within ``±0.6 f_max`` (for demos and tests).

        Parameters
        ----------
        n_steps : int
            Number of controls ``T``.
        seed : int, numpy.random.Generator or None
            Seeds the draws.

        Returns
        -------
        numpy.ndarray, shape (T, q)
        """
        n_steps = check_count(n_steps, "n_steps")
        gen = as_generator(seed)
        cfg = self.config
        steps = np.clip(
            gen.normal(0.0, 0.15 * cfg.f_max, (n_steps, self.control_dim)), -cfg.df_max, cfg.df_max
        )
        walk = np.clip(np.cumsum(steps, axis=0), -0.6 * cfg.f_max, 0.6 * cfg.f_max)
        du = np.diff(walk, axis=0, prepend=np.zeros((1, self.control_dim)))
        return np.clip(du, -cfg.df_max, cfg.df_max)  # rounding of the difference
