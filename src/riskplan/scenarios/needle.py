"""Scenario 1 of the deformable-planning paper (Patil, van den Berg & Alterovitz, RSS 2011,
section V-A): a car without reverse — a planar model of a bevel-tip steerable needle —
moving through a deformable unit square fixed at its four corners (or, from a scenario file,
a tissue of any outline with a named fixed boundary: :class:`NeedleConfig`). The paper: "the robot
traverses the deformable plane and pushes its surface forward"; the robot rides on the
tissue, so where the tissue goes, the robot goes.

Robot (paper V-A, Euler update with time step τ), **in the tissue's material frame**: the
material pose ``(X, Y, Θ)`` (reference coordinates of the material point the tip is at,
heading measured in the reference configuration) follows the paper's car::

    X_{t+1} = X_t + τ v_t cos Θ_t
    Y_{t+1} = Y_t + τ v_t sin Θ_t
    Θ_{t+1} = Θ_t + τ v_t tan φ_t / (r_min tan φ_max)

with ``v ∈ [0, v_max]``, ``φ ∈ [−φ_max, φ_max]``, ``v_max = 0.5``, ``φ_max = π/3``,
``τ = 0.1``, ``r_min = 0.25``; at ``|φ| = φ_max`` the curvature is ``1/r_min``. The tip
cuts its way through the material, so its kinematics hold relative to the material.

Tissue: isotropic linear elasticity (plane stress, unit thickness) on a triangle mesh of
the unit square with the four corner nodes fixed. After each step the robot pushes the
tissue with a force of magnitude ``f_int = params.force_scale`` (nominal 1) along its
direction of motion, ``f = f_int (cos Θ, sin Θ)``, applied as a point load at the
material point ``X`` under the robot (consistent nodal forces ``λ_a(X) f``); the
quasi-static displacement is ``u = K⁻¹ f``.

World pose (what is sensed and what meets the deformed obstacles and goal)::

    x = X + u(X)                      (P1 interpolation of the nodal displacement)
    θ = Θ

The heading the deformation would give, the direction of ``F t`` (``F = I + ∇u``
constant in the element holding X, ``t = (cos Θ, sin Θ)``; :func:`world_pose`), differs
from Θ by 0.012 rad on average and 0.055 rad at most at E = 50 (measured,
docs/scenarios.md), below one step's steering noise (5°), and the P1 gradient is
discontinuous across element edges: the heading would jump by up to that much whenever
the tip crosses an edge, a mesh artefact that the finite-difference linearisation turns
into spurious gains. So the world heading is taken as Θ. Obstacles and the goal region are embedded in the tissue: polygons
of material points whose current positions are ``X + u(X)``.

Modelling choices the paper leaves open (documented in docs/scenarios.md):

* the load and its direction are those of the reference configuration (small-strain
  linear elasticity: loads act on the reference body; the rotation between ``t`` and
  ``F t`` is second order in the load and is measured in docs/scenarios.md);
* the force is applied whatever the speed (the needle pushes whenever it is in the
  tissue; this keeps ``g`` smooth in ``v`` for numerical linearisation), and is zero
  once the robot has left the tissue (material point outside the reference square; world
  pose = material pose there);
* the tissue has no memory: the displacement is the response to the current push only.

Full state: material pose, displacement, step index; the world pose is a function of them
(kept in the state so that it is computed once). Sensing ``z = (x, y) + n``,
``n ~ N(0, σ² I)``: the world position, as the paper senses the robot.

Reduced state, two frames (``frame``; :meth:`NeedleScenario.with_frame`):

* ``"world"`` (default; the paper's formulation, used by the reproduction's figures):
  ``x = (x, y, θ)``, the world pose, what LQG-MP checks against the deformed obstacles;
  ``z = H x + n`` with the constant ``H = [I₂ 0]``. With the tissue carrying the robot,
  the world pose does not determine the next one (the deformation is hidden state), and
  the fitted ``A_t`` of :func:`riskplan.control.linearize` are ill-conditioned
  (docs/control.md, "Calibration").
* ``"material"`` (beyond the paper): ``x = (X, Y, Θ)``, the material pose. Its dynamics
  are the plain car above, whatever the tissue does; the tissue enters only the
  measurement, ``z = h(x; s) + n`` with ``h(X, Y, Θ; s) = X + u(X; Θ, s)``, whose Jacobian
  ``H_t = ∂h/∂x`` at the plan's pose is taken by central differences
  (:meth:`NeedleScenario.observation_jacobian`). Obstacles and goal are fixed sets of
  material points, so LQG-MP checks ``x`` against the reference polygons
  (:meth:`NeedleScenario.state_obstacles`): the world position is inside a deformed
  obstacle exactly when the material point is inside the reference one (the map
  ``X ↦ X + u(X)`` is one-to-one while no element inverts), up to the deformed polygon's
  edges being drawn straight between moved vertices.
"""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array, as_generator, check_choice, check_count
from riskplan.errors import InvalidInputError
from riskplan.geometry2d import points_in_polygon
from riskplan.scenarios import base, needle_frames
from riskplan.scenarios.base import (
    FRAMES,
    FEMScenario,
    SimParams,
    apply_actuation_noise,
    check_control,
)
from riskplan.scenarios.needle_config import NeedleConfig, NeedleState
from riskplan.scenarios.needle_mesh import MeshData, NeedleModel, world_pose
from riskplan.scenarios.needle_space import car_steer, car_step, needle_box_space
from riskplan.scenarios.space import BoxSpace

# the configuration, state, kinematics and world pose live in needle_config, needle_space and
# needle_mesh; this module hands them on with the scenario
__all__ = [
    "NeedleConfig",
    "NeedleScenario",
    "NeedleState",
    "car_steer",
    "car_step",
    "world_pose",
]


class NeedleScenario(FEMScenario):
    """The needle / car scenario as a :class:`~riskplan.scenarios.base.Simulator`.

    Parameters
    ----------
    config: :class:`NeedleConfig` (paper values by default).
    distribution: parameter distribution S used by :meth:`sample_params` (default: the
        nominal case, i.e. always ``nominal_params``).
    cache_size: FEM models kept (one per distinct ``(E, ν, n_elements)``).
    frame: the reduced state's frame, ``"world"`` (default) or ``"material"`` (:data:`FRAMES`).

    Dimensions: controls ``(v, φ)`` (q = 2), reduced state ``(x, y, θ)`` (p = 3),
    measurements ``(x, y)`` (2).
    """

    control_dim = 2
    state_dim = 3
    obs_dim = 2
    #: where the 2-D points of x are (LQG-MP, :mod:`riskplan.control.lqgmp`): the position
    collision_point_indices = ((0, 1),)
    #: the A-runs of :func:`riskplan.control.linearize` perturb the 2 controls: to first
    #: order they span 2 directions of x; the tissue's second-order response lifts X_t to
    #: full numerical rank with tiny singular values whose inverse gave LQR gains of 10^5
    a_max_rank = 2
    goal_point_indices = (0, 1)
    name = "needle"
    state_type = NeedleState

    def __init__(
        self,
        config: NeedleConfig | None = None,
        distribution=None,
        cache_size: int = 32,
        frame: str = "world",
    ):
        super().__init__(config or NeedleConfig(), distribution, cache_size)
        #: the reduced state's frame (module docstring): ``"world"`` (the paper's) or ``"material"``
        self.frame = check_choice(frame, FRAMES, "frame")
        self._bounds = np.array(
            [[0.0, self.config.v_max], [-self.config.phi_max, self.config.phi_max]]
        )
        self._bounds.setflags(write=False)
        H = np.zeros((2, 3))
        H[0, 0] = H[1, 1] = 1.0
        H.setflags(write=False)
        self.observation_matrix = H
        cov = self.config.sensing_std**2 * np.eye(2)
        cov.setflags(write=False)
        self.sensing_cov = cov

    @property
    def state_scale(self) -> np.ndarray:
        """``(3,)`` acceptable deviation of each reduced-state component, the scale of the
        LQR's default Bryson weights (:func:`riskplan.control.lqg_controller`): the goal
        radius for the position ``(x, y)``, and ``goal_radius / r_min`` for the heading
        (the heading change that, turned at the minimum radius, moves the tip by one goal
        radius)."""
        r = self.config.goal_radius
        return np.array([r, r, r / self.config.r_min])

    # ---- protocol ------------------------------------------------------------------
    @property
    def control_bounds(self) -> np.ndarray:
        """``[[0, v_max], [−φ_max, φ_max]]``."""
        return self._bounds

    def planning_space(self) -> BoxSpace:
        """The RRT's space (:class:`~riskplan.scenarios.space.PlanningScenario`).

        Returns
        -------
        BoxSpace
            The tissue's bounding box for ``(x, y)`` (the rectangle, or the outline's box:
            samples outside a non-rectangular outline leave the tissue, which the planner's
            state checks reject), the metric ``(x, y)`` plus ``r_min · θ``
            (a heading error of 1 rad counts like the arc the car needs to turn by it),
            3 steps per extension (at most 0.15 length units, about the goal disk's
            diameter) and :func:`car_steer` as the local steering rule.
        """
        return needle_box_space(self.config)

    def actuation_cov(self) -> tuple:
        """The actuation covariance of ``config.actuation_std = (σ_v, σ_φ)``:

        .. math::

            W = \\operatorname{diag}(\\sigma_v^2, \\sigma_\\varphi^2)

        (the paper scene: ``diag(0.05², (5°)²)``,
        :func:`riskplan.scenarios.uncertainty.needle_actuation_cov`).

        Returns
        -------
        tuple of tuple of float, shape (2, 2)
            ``W`` in speed² and rad², as :class:`SimParams` ``actuation_cov`` holds it.
        """
        sv, sp = self.config.actuation_std
        return ((sv * sv, 0.0), (0.0, sp * sp))

    def _make_mesh_data(self, n_elements: int) -> MeshData:
        return MeshData(self.config, n_elements)

    def _make_model(self, params: SimParams) -> NeedleModel:
        return NeedleModel(self.mesh_data(params.n_elements), params, self.config.plane)

    def initial_state(self, params: SimParams | None = None, pose=None) -> NeedleState:
        """The start state ``y_0``: undeformed tissue (world pose = material pose), ``t = 0``.

        Parameters
        ----------
        params : SimParams, optional
            Default: the nominal parameters (their ``n_elements`` picks the mesh).
        pose : array_like, shape (3,), optional
            The material pose ``(X, Y, Θ)`` of the robot; default ``config.start``.

        Returns
        -------
        NeedleState
        """
        params = params or self.nominal_params
        d = self.mesh_data(params.n_elements)
        p = self.config.start if pose is None else pose
        p = as_array(p, "pose", shape=(3,))
        return NeedleState(
            t=0,
            displacement=np.zeros((d.mesh.n_nodes, 2)),
            n_elements=params.n_elements,
            pose=p,
            material=p,
        )

    def step(self, state: NeedleState, control, params: SimParams | None = None) -> NeedleState:
        """``y_{t+1} = g(y_t, u_t, s)`` (paper eq. 1 with the V-A car in the material frame
        and a linear FEM; module docstring):

        .. math::

            (X, Y, \\Theta)_{t+1} = \\mathrm{car}((X, Y, \\Theta)_t, \\tilde u_t), \\qquad
            K u_{t+1} = \\lambda(X_{t+1})\\, f_{\\mathrm{int}} (\\cos\\Theta_{t+1},
            \\sin\\Theta_{t+1}), \\qquad x_{t+1} = X_{t+1} + u_{t+1}(X_{t+1})

        with ``ũ_t = clip(u_t + w_t)`` under actuation noise in ``params``, else ``u_t``.

        Parameters
        ----------
        state : NeedleState
            ``y_t`` on the mesh of ``params``.
        control : array_like, shape (2,)
            ``(v, φ)`` inside :attr:`control_bounds` (else
            :class:`~riskplan.errors.InvalidInputError`).
        params : SimParams, optional
            ``s`` (default: the nominal parameters).

        Returns
        -------
        NeedleState
            ``y_{t+1}``; ``state`` is not changed.
        """
        params = params or self.nominal_params
        self._check_state(state, params)
        u = check_control(control, self._bounds)
        u = apply_actuation_noise(u, params, state.t, self._bounds)
        cfg = self.config
        mat = car_step(
            state.material, u[0], u[1], tau=cfg.tau, r_min=cfg.r_min, phi_max=cfg.phi_max
        )
        disp, pose = self._tissue_response(mat, params)
        # new arrays: no defensive copies (a hot path of the planners)
        return NeedleState._owned(state.t + 1, disp, state.n_elements, pose, mat)

    def _tissue_response(self, mat: np.ndarray, params: SimParams):
        """New arrays ``(displacement (n_nodes, 2), world pose (3,))`` of the push at the
        material pose ``mat (3,)`` (``NeedleModel.push_response`` of ``params``' model)."""
        return self.model(params).push_response(mat, params.force_scale)

    def transfer_state(self, state: NeedleState, params: SimParams) -> NeedleState:
        """``state`` on the mesh of ``params``: the same material pose and step index, the
        displacement and world pose of its push recomputed there (undeformed at ``t = 0``).
        Lets :func:`riskplan.control.linearize` run mesh-size draws of ``M_t`` on their own
        meshes (the robot's world offset under the load depends on the mesh).

        Parameters
        ----------
        state : NeedleState
            A state on any mesh.
        params : SimParams
            Their ``n_elements`` and material give the new mesh and tissue response.

        Returns
        -------
        NeedleState
        """
        if not isinstance(state, NeedleState):
            raise InvalidInputError(f"state: expected a NeedleState, got {type(state).__name__}")
        d = self.mesh_data(params.n_elements)
        mat = np.array(state.material)
        if state.t == 0:
            disp, pose = np.zeros((d.mesh.n_nodes, 2)), mat.copy()
        else:
            disp, pose = self._tissue_response(mat, params)
        return NeedleState._owned(state.t, disp, params.n_elements, pose, mat)

    def nodal_forces(self, state: NeedleState, params: SimParams | None = None) -> np.ndarray:
        """The consistent nodal forces the robot applies in ``state`` (what
        ``state.displacement`` balances; for residual checks and plots):
        ``f_a = λ_a(X) f_int (cos Θ, sin Θ)`` on the nodes of the element holding ``X``.

        Parameters
        ----------
        state : NeedleState
        params : SimParams, optional
            Their ``force_scale`` is ``f_int`` (default: the nominal parameters).

        Returns
        -------
        numpy.ndarray, shape (n_nodes, 2)
            Zero at ``t = 0`` (the robot has not pushed yet) and outside the tissue.
        """
        params = params or self.nominal_params
        self._check_state(state, params)
        d = self.mesh_data(state.n_elements)
        if state.t == 0:
            return np.zeros((d.mesh.n_nodes, 2))
        return d.push_forces(state.material, params.force_scale)

    # the reduced state's frames (module docstring): functions of needle_frames, bound here
    with_frame = base.with_frame
    reduced = needle_frames.reduced
    measure = needle_frames.measure
    observation_jacobian = needle_frames.observation_jacobian
    state_obstacles = needle_frames.state_obstacles
    state_goal = needle_frames.state_goal
    observe = needle_frames.observe

    # ---- geometry of a state -----------------------------------------------------------
    def obstacles(self, state: NeedleState) -> list[np.ndarray]:
        """Deformed obstacle polygons in ``state``: the current positions ``X + u(X)`` of
        their reference vertices.

        Parameters
        ----------
        state : NeedleState

        Returns
        -------
        list of numpy.ndarray, each shape (k_i, 2)
        """
        pts = self._points(state)
        s = self._data(state).obstacle_slices
        return [pts[s[i] : s[i + 1]] for i in range(len(s) - 1)]

    def goal(self, state: NeedleState) -> np.ndarray:
        """Deformed goal polygon (the goal disk's 24-gon of material points, moved).

        Parameters
        ----------
        state : NeedleState

        Returns
        -------
        numpy.ndarray, shape (24, 2)
        """
        return self._points(state)[self._data(state).goal_slice]

    def goal_center(self, state: NeedleState) -> np.ndarray:
        """Current position of the material point at the goal's centre.

        Parameters
        ----------
        state : NeedleState

        Returns
        -------
        numpy.ndarray, shape (2,)
        """
        return self._points(state)[self._data(state).goal_center_index]

    def inside(self, state: NeedleState) -> bool:
        """Whether the robot is in the tissue: its material point lies in the reference
        square (or the reference outline, boundary included).

        Parameters
        ----------
        state : NeedleState

        Returns
        -------
        bool
        """
        x, y = state.material[0], state.material[1]
        if self.config.outline is not None:
            return bool(points_in_polygon(np.array([[x, y]]), self.config.outline)[0])
        return bool(0.0 <= x <= self.config.width and 0.0 <= y <= self.config.height)

    def in_collision(self, state: NeedleState) -> bool:
        """Whether the robot's world position lies inside a deformed obstacle.

        Parameters
        ----------
        state : NeedleState

        Returns
        -------
        bool
        """
        p = state.pose[None, :2]
        x, y = float(p[0, 0]), float(p[0, 1])
        for poly in self.obstacles(state):
            lo, hi = poly.min(0), poly.max(0)
            if lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1] and points_in_polygon(p, poly)[0]:
                return True
        return False

    def in_goal(self, state: NeedleState) -> bool:
        """Whether the robot's world position lies inside the deformed goal polygon.

        Parameters
        ----------
        state : NeedleState

        Returns
        -------
        bool
        """
        return bool(points_in_polygon(state.pose[None, :2], self.goal(state))[0])

    def goal_distance(self, state: NeedleState) -> float:
        """Distance from the robot's world position to the (deformed) goal centre.

        Parameters
        ----------
        state : NeedleState

        Returns
        -------
        float
            In scene units.
        """
        return float(np.linalg.norm(state.pose[:2] - self.goal_center(state)))

    def path(self, states) -> np.ndarray:
        """Robot world positions along a list of states.

        Parameters
        ----------
        states : sequence of NeedleState
            ``T`` states.

        Returns
        -------
        numpy.ndarray, shape (T, 2)
        """
        return np.array([s.pose[:2] for s in states])

    def random_controls(self, n_steps: int, seed=None) -> np.ndarray:
        """Random controls for demos and tests: speed in ``[0.6, 1] v_max``, steering a
        smoothed random walk inside the bounds.

        Parameters
        ----------
        n_steps : int
            Number of controls ``T``.
        seed : int, numpy.random.Generator or None
            Seeds the draws.

        Returns
        -------
        numpy.ndarray, shape (T, 2)
            ``(v, φ)`` per step.
        """
        n_steps = check_count(n_steps, "n_steps")
        gen = as_generator(seed)
        v = gen.uniform(0.6, 1.0, n_steps) * self.config.v_max
        phi = np.clip(np.cumsum(gen.normal(0.0, 0.25, n_steps)) * 0.5, -1, 1) * self.config.phi_max
        return np.stack([v, phi], axis=1)
