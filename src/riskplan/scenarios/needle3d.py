"""A bevel-tip steerable needle in a 3-D deformable block: the 2-D needle of the deformable
paper (Patil, van den Berg & Alterovitz, RSS 2011, V-A; :mod:`riskplan.scenarios.needle`)
lifted to SE(3) with the unicycle model of Webster et al. 2006
(:mod:`riskplan.scenarios.bevel`), riding on a tetrahedral linear-elastic tissue
(:mod:`riskplan.scenarios.tissue3d`).

**Material frame.** The tip frame ``g = (R, p)`` moves in the tissue's reference
configuration (the tip cuts its way through the material, so its kinematics hold relative
to it)::

    g_{t+1} = g_t exp(τ ξ̂(u_t)),   ξ = (0, 0, v, ρ κ v, 0, ω)

with controls ``u = (v, ω)`` (``v ∈ [0, v_max]``, ``ω ∈ [−ω_max, ω_max]``) or, with duty
cycling, ``u = (v, ω, ρ)``, ``ρ ∈ [0, 1]``.

**Tissue.** After each step the needle pushes the tissue with ``f = f_int e₃`` (along its
axis, the direction of insertion; ``f_int = params.force_scale``) at its material point
``X = p_{t+1}``, as consistent nodal forces ``λ_a(X) f`` of the tetrahedron holding it; the
displacement is the quasi-static response ``u = K⁻¹ f`` (no memory, as in 2-D).

**World.** The tip is where the tissue carried its material point::

    x = X + u(X),     frame = R (the material frame, as the 2-D heading is Θ)

Obstacles (balls and boxes) and the target (a ball) are sets of material points; their
deformed images are taken affine per body: centre ``c + u(c)``, ``F = I + ∇u`` fitted by
least squares to the displacements of the body's sample points (the ball's six axis points
at ``c ± r e_k``, the box's eight corners), so a deformed ball is an ellipsoid and a box a
parallelepiped (:class:`riskplan.geometry3d.ConvexBody`). Success = the world tip in the
deformed target at the end, never inside a deformed obstacle, never outside the block.

**Reduced state** ``x (12,)`` = (world position, ``e₁``, ``e₂``, ``e₃``); sensing
``z = x[:3] + n``, ``n ~ N(0, σ² I₃)`` (the tip position, as from 3-D ultrasound or CT).

**Frames** (as the 2-D needle, :data:`FRAMES`; ``frame=`` or :meth:`Needle3DScenario.with_frame`):
``"world"`` (the default) reads ``x`` as above; ``"material"`` reads the tip's material
pose ``(X, e₁, e₂, e₃)``. In the material frame a material, mesh or force draw does not
move ``x`` at all (the tip cuts its way through the material whatever its stiffness): it
moves what is *sensed*, ``z = X + u(X; s) + n``, the same way at every step. The
linearisation then sees the draw as a measurement bias (``H_t = ∂z/∂x`` by central
differences, :meth:`Needle3DScenario.observation_jacobian`) instead of fresh process
noise at every step, and LQG-MP checks ``X`` against the bodies of material points
(balls and boxes, :meth:`Needle3DScenario.state_obstacles` / :meth:`state_goal`), which
the tissue carries along with the tip. Simulation, collision and goal tests are the same
in both frames.

Noise scaled to the scene as in 2-D: ``σ = 0.01 · max(size)``; actuation
``(0.1 v_max, 0.1 ω_max[, 0.1])``.
"""

from __future__ import annotations

import functools

import numpy as np

from riskplan._validation import as_array, as_generator, check_choice, check_count
from riskplan.errors import InvalidInputError
from riskplan.geometry3d import ConvexBody
from riskplan.scenarios.base import (
    FRAMES,
    FEMScenario,
    SimParams,
    apply_actuation_noise,
    check_control,
    gaussian_noise,
)
from riskplan.scenarios.bevel import _pose_vector_step, pose_step_jacobian
from riskplan.scenarios.needle3d_config import Needle3DConfig, Needle3DState, _MeshData3D
from riskplan.scenarios.needle3d_frames import Needle3DFrames
from riskplan.scenarios.needle3d_moments import Needle3DMoments
from riskplan.scenarios.needle3d_space import Needle3DSpace, needle3d_steer

__all__ = [
    "PLANNING_ELEMENTS",
    "Needle3DConfig",
    "Needle3DScenario",
    "Needle3DState",
    "needle3d_steer",
]

#: Tetrahedra of the planning mesh (a 6 × 6 × 6 grid of cubes, 6 tetrahedra each).
PLANNING_ELEMENTS = 1296


class Needle3DScenario(Needle3DMoments, Needle3DFrames, FEMScenario):
    """The 3-D needle as a :class:`~riskplan.scenarios.base.Simulator` (module docstring).

    Dimensions: controls ``(v, ω)`` (q = 2; ``(v, ω, ρ)`` with duty cycling), reduced state
    ``(x, y, z, e₁, e₂, e₃)`` (p = 12), measurements the tip position (3).
    """

    state_dim = 12
    obs_dim = 3
    #: LQG-MP checks the 3-D point x[0:3] against convex bodies (:mod:`riskplan.control.lqgmp3d`)
    workspace_dim = 3
    goal_point_indices = (0, 1, 2)
    name = "needle3d"
    state_type = Needle3DState

    def __init__(
        self,
        config: Needle3DConfig | None = None,
        distribution=None,
        cache_size: int = 40,
        frame: str = "world",
    ):
        super().__init__(config or Needle3DConfig(), distribution, cache_size)
        self.frame = check_choice(frame, FRAMES, "frame")
        cfg = self.config
        self.control_dim = 3 if cfg.duty_cycle else 2
        b = [[0.0, cfg.v_max], [-cfg.omega_max, cfg.omega_max], [0.0, 1.0]]
        self._bounds = np.array(b[: self.control_dim])
        self._bounds.setflags(write=False)
        H = np.zeros((3, 12))
        H[:, :3] = np.eye(3)
        H.setflags(write=False)
        self.observation_matrix = H
        cov = float(cfg.sensing_std) ** 2 * np.eye(3)
        cov.setflags(write=False)
        self.sensing_cov = cov
        #: the A-runs perturb q controls: fit at most q directions (as the 2-D needle)
        self.a_max_rank = self.control_dim

    # ---- parameters ---------------------------------------------------------------
    @property
    def nominal_params(self) -> SimParams:
        """The distribution's planning parameters, else the config's material on the
        :data:`PLANNING_ELEMENTS` mesh, ``f_int = 1``, no actuation noise."""
        if self.distribution is not None:
            return self.distribution.planning_params
        cfg = self.config
        return SimParams(
            youngs_modulus=cfg.youngs_modulus,
            poissons_ratio=cfg.poissons_ratio,
            n_elements=PLANNING_ELEMENTS,
        )

    def actuation_cov(self) -> tuple:
        """``diag(σ²)`` of ``config.actuation_std``.

        Returns
        -------
        tuple of tuple of float, shape (q, q)
            The actuation noise covariance.
        """
        s = self.config.actuation_std
        return tuple(
            tuple(s[i] ** 2 if i == j else 0.0 for j in range(len(s))) for i in range(len(s))
        )

    @property
    def control_bounds(self) -> np.ndarray:
        """``[[0, v_max], [−ω_max, ω_max]]`` (and ``[0, 1]`` for ρ)."""
        return self._bounds

    @property
    def goal_radius(self) -> float:
        return float(self.config.target_radius)

    @property
    def state_scale(self) -> np.ndarray:
        """``(12,)``: the target radius for the position and ``κ r`` for each frame component
        (the frame error that, turned at the needle's curvature, moves the tip one radius)."""
        r = self.config.target_radius
        return np.concatenate([np.full(3, r), np.full(9, r * self.config.curvature)])

    def mesh_data(self, n_elements: int):
        """The block and tracked-point layout, cached per grid (counts of one grid share it).

        Parameters
        ----------
        n_elements : int
            Requested number of tetrahedra (rounded to a grid by :func:`~riskplan.scenarios.tissue3d.grid_for`).

        Returns
        -------
        object
            ``block`` (a ``TetBlock``) and the tracked points' layout.
        """
        d = self._meshes.get(n_elements)
        if d is not None:  # the hot path: before any import
            return d
        from riskplan.scenarios.tissue3d import grid_for

        key = grid_for(self.config.size, n_elements)
        d = self._meshes.get(key)
        if d is not None:
            self._meshes[n_elements] = d
            return d
        if d is None:
            d = self._meshes[key] = self._meshes[n_elements] = _MeshData3D(self.config, n_elements)
            d.model_count = n_elements  # the count this grid's models are keyed by
        return d

    def _make_model(self, params: SimParams):
        d = self.mesh_data(params.n_elements)
        if d.model_count != params.n_elements:  # counts on one grid share the first's model
            return self.model(params.replace(n_elements=d.model_count))
        return d.block.model(params.youngs_modulus, params.poissons_ratio)

    # ---- protocol -----------------------------------------------------------------
    def initial_state(self, params: SimParams | None = None) -> Needle3DState:
        """Tip at ``config.start`` with the start frame, undeformed tissue, ``t = 0``.

        Parameters
        ----------
        params : SimParams or None
            The simulation parameters (``None``: :attr:`nominal_params`).

        Returns
        -------
        Needle3DState
            The state at ``t = 0``.
        """
        params = params or self.nominal_params
        d = self.mesh_data(params.n_elements)
        cfg = self.config
        mat = np.concatenate([np.asarray(cfg.start, dtype=np.float64), cfg.start_frame.T.ravel()])
        return Needle3DState(
            t=0,
            displacement=np.zeros((d.block.tracked.shape[0], 3)),
            n_elements=params.n_elements,
            pose=mat,
            material=mat,
            applied=np.zeros(self.control_dim),
        )

    def _rho(self, u) -> float:
        return float(u[2]) if self.control_dim == 3 else 1.0

    def step(self, state: Needle3DState, control, params: SimParams | None = None) -> Needle3DState:
        """``y_{t+1} = g(y_t, u_t, s)``: the exact screw step of the material frame, the
        push ``f_int e₃`` at the new material point, the world pose (module docstring).

        Parameters
        ----------
        state : Needle3DState
            The state ``y_t``.
        control : array_like, shape (q,)
            The control ``(v, ω)`` (``(v, ω, ρ)`` with duty cycling).
        params : SimParams or None
            The simulation parameters (``None``: :attr:`nominal_params`).

        Returns
        -------
        Needle3DState
            The state ``y_{t+1}``.
        """
        params = params or self.nominal_params
        self._check_state(state, params)
        u = check_control(control, self._bounds)
        u = apply_actuation_noise(u, params, state.t, self._bounds)
        cfg = self.config
        # needle_step on the pose vector, compiled (equal to rounding)
        mat = _pose_vector_step(
            state.material, float(u[0]), float(u[1]), cfg.tau, cfg.curvature, self._rho(u)
        )
        disp, pose = self._tissue_response(mat, params)
        return Needle3DState(
            t=state.t + 1,
            displacement=disp,
            n_elements=state.n_elements,
            pose=pose,
            material=mat,
            applied=u,
        )

    def _tissue_response(self, mat: np.ndarray, params: SimParams):
        d = self.mesh_data(params.n_elements)
        k = d.block.tracked.shape[0]
        if params.force_scale == 0.0 or not d.block.contains(mat[:3]):
            return np.zeros((k, 3)), mat.copy()
        elem, lam = d.block.locate_point(mat[:3])
        model = self.model(params)
        u_tip, tracked = model.point_load(elem, lam, params.force_scale * mat[9:12])
        pose = mat.copy()
        pose[:3] += u_tip
        return tracked, pose

    def transfer_state(self, state: Needle3DState, params: SimParams) -> Needle3DState:
        """``state`` on the mesh of ``params`` (same material pose, push recomputed there).

        Parameters
        ----------
        state : Needle3DState
            The state on its own mesh.
        params : SimParams
            Parameters whose mesh the state is moved to.

        Returns
        -------
        Needle3DState
            The same material pose with the push recomputed on the new mesh.
        """
        if not isinstance(state, Needle3DState):
            raise InvalidInputError(f"state: expected a Needle3DState, got {type(state).__name__}")
        d = self.mesh_data(params.n_elements)
        mat = np.array(state.material)
        if state.t == 0:
            disp, pose = np.zeros((d.block.tracked.shape[0], 3)), mat.copy()
        else:
            disp, pose = self._tissue_response(mat, params)
        return Needle3DState(
            t=state.t,
            displacement=disp,
            n_elements=params.n_elements,
            pose=pose,
            material=mat,
            applied=state.applied,
        )

    def a_prior(self, y_next: Needle3DState, params: SimParams) -> np.ndarray:
        """``(12, 12)`` the exact Jacobian of the kinematic step that led to ``y_next``
        (:func:`riskplan.scenarios.bevel.pose_step_jacobian`; the tissue's offset of the
        world position is left to the fit on the excited directions).

        Parameters
        ----------
        y_next : Needle3DState
            The state after the step (its ``applied`` control is used).
        params : SimParams
            The simulation parameters (unused by the kinematic Jacobian).

        Returns
        -------
        numpy.ndarray, shape (12, 12)
            The Jacobian of the reduced state.
        """
        u = y_next.applied
        cfg = self.config
        return pose_step_jacobian(u[0], u[1], tau=cfg.tau, kappa=cfg.curvature, rho=self._rho(u))

    def reduced(self, state: Needle3DState) -> np.ndarray:
        """``x (12,)`` (a copy): the world position and the material frame, or in the
        material frame the material pose (module docstring).

        Parameters
        ----------
        state : Needle3DState
            The full state.

        Returns
        -------
        numpy.ndarray, shape (12,)
            The reduced state ``x``.
        """
        return np.array(state.pose if self.frame == "world" else state.material)

    def observe(self, x, noise=None, rng=None) -> np.ndarray:
        """``z = x[:3] + n`` (the tip position).

        Parameters
        ----------
        x : array_like, shape (12,)
            The reduced state.
        noise : array_like, shape (3,), optional
            The sensing noise to add; drawn with ``rng`` when ``None``.
        rng : int, numpy.random.Generator or None
            Seeds the drawn noise.

        Returns
        -------
        numpy.ndarray, shape (3,)
            The measured tip position.
        """
        x = as_array(x, "x", shape=(12,))
        return x[:3] + gaussian_noise(self.sensing_cov, noise, rng, 3)

    # ---- geometry -----------------------------------------------------------------
    def _bodies(self, state: Needle3DState) -> list[ConvexBody]:
        """The deformed bodies (obstacles, then the target), computed once per state."""
        cached = state.__dict__.get("_bodies")
        if cached is not None:
            return cached
        d = self._data(state)
        centres, shapes = self._affine(state)
        out = [ConvexBody(k, c, A) for k, c, A in zip(d.kinds, centres, shapes)]
        state.__dict__["_bodies"] = out  # a cache on a frozen state: a function of its fields
        return out

    def obstacles(self, state: Needle3DState) -> list[ConvexBody]:
        """The deformed obstacles (ellipsoids, parallelepipeds) in ``state``.

        Parameters
        ----------
        state : Needle3DState
            The full state.

        Returns
        -------
        list of ConvexBody
            The deformed obstacles.
        """
        return self._bodies(state)[:-1]

    def goal(self, state: Needle3DState) -> ConvexBody:
        """The deformed target (an ellipsoid).

        Parameters
        ----------
        state : Needle3DState
            The full state.

        Returns
        -------
        ConvexBody
            The deformed target.
        """
        return self._bodies(state)[-1]

    def goal_center(self, state: Needle3DState) -> np.ndarray:
        """The deformed target's centre.

        Parameters
        ----------
        state : Needle3DState
            The full state.

        Returns
        -------
        numpy.ndarray, shape (3,)
            The centre in world coordinates.
        """
        return self.goal(state).centre

    def inside(self, state: Needle3DState) -> bool:
        """The tip's material point lies in the block.

        Parameters
        ----------
        state : Needle3DState
            The full state.

        Returns
        -------
        bool
            Whether the tip is inside the tissue block.
        """
        return self._data(state).block.contains(state.material[:3])

    def in_collision(self, state: Needle3DState) -> bool:
        """The world tip lies in a deformed obstacle.

        Parameters
        ----------
        state : Needle3DState
            The full state.

        Returns
        -------
        bool
            Whether the tip is in collision.
        """
        return bool(np.any(self._gauges(state)[:-1] <= 1.0))

    def in_goal(self, state: Needle3DState) -> bool:
        """The world tip lies in the deformed target.

        Parameters
        ----------
        state : Needle3DState
            The full state.

        Returns
        -------
        bool
            Whether the tip is in the goal.
        """
        return bool(self._gauges(state)[-1] <= 1.0)

    def goal_distance(self, state: Needle3DState) -> float:
        """Distance of the world tip from the deformed target's centre (its tracked sample).

        Parameters
        ----------
        state : Needle3DState
            The full state.

        Returns
        -------
        float
            The distance (length units of the block).
        """
        d = self._data(state)
        a = d.slices[-1][0]
        c = d.centres[-1] + state.displacement[a]
        return float(np.linalg.norm(state.pose[:3] - c))

    def path(self, states) -> np.ndarray:
        """World tip positions ``(T, 3)``.

        Parameters
        ----------
        states : sequence of Needle3DState
            The states of an execution.

        Returns
        -------
        numpy.ndarray, shape (T, 3)
            The world tip positions.
        """
        return np.array([s.pose[:3] for s in states])

    def nodal_displacement(self, state: Needle3DState, params: SimParams | None = None):
        """The block's nodal displacement ``(N, 3)`` in ``state`` (recomputed from the push:
        the state keeps the tracked points only).

        Parameters
        ----------
        state : Needle3DState
            The full state.
        params : SimParams or None
            The simulation parameters (``None``: :attr:`nominal_params`).

        Returns
        -------
        numpy.ndarray
            ``(N, 3)`` [m].
        """
        params = params or self.nominal_params
        self._check_state(state, params)
        d = self.mesh_data(state.n_elements)
        N = d.block.n_nodes
        if state.t == 0 or params.force_scale == 0 or not d.block.contains(state.material[:3]):
            return np.zeros((N, 3))
        elem, lam = d.block.locate(state.material[:3])
        F = np.zeros((N, 3))
        F[d.block.tets[elem[0]]] = np.outer(lam[0], params.force_scale * state.material[9:12])
        return self.model(params).solve(F)

    def random_controls(self, n_steps: int, seed=None) -> np.ndarray:
        """``(n_steps, q)`` random controls inside the bounds (demos and tests).

        Parameters
        ----------
        n_steps : int
            Number of controls.
        seed : int, numpy.random.Generator or None
            Seeds the draws.

        Returns
        -------
        numpy.ndarray, shape (n_steps, q)
            Uniform controls inside :attr:`control_bounds`.
        """
        n_steps = check_count(n_steps, "n_steps")
        gen = as_generator(seed)
        lo, hi = self._bounds[:, 0], self._bounds[:, 1]
        u = lo + gen.random((n_steps, self.control_dim)) * (hi - lo)
        u[:, 0] = gen.uniform(0.6, 1.0, n_steps) * self.config.v_max
        return u

    # ---- planning -----------------------------------------------------------------
    def expected_goal_point(self, params: SimParams | None = None) -> np.ndarray:
        """``(3,)`` where the world tip is when its material point is the target centre,
        reached along the line from the start: ``c + u(c)`` under the push there. The tissue
        carries the tip and the target alike, so this is also where the deformed target's
        centre is then; the undeformed centre ``c`` lies about ``|u(c)|`` (0.07 on the
        default scene, most of the target radius) behind it, and a tree steered there stops
        short of the deformed target.

        Parameters
        ----------
        params : SimParams or None
            The simulation parameters (``None``: :attr:`nominal_params`).

        Returns
        -------
        numpy.ndarray, shape (3,)
            The expected world goal point.
        """
        params = params or self.nominal_params
        cfg = self.config
        c = np.asarray(cfg.target_center, dtype=np.float64)
        e3 = c - np.asarray(cfg.start, dtype=np.float64)
        n = float(np.linalg.norm(e3))
        if n == 0.0:
            return c
        mat = np.concatenate([c, np.zeros(6), e3 / n])
        return self._tissue_response(mat, params)[1][:3]

    def planning_space(self) -> Needle3DSpace:
        """The RRT's space (:class:`Needle3DSpace`): the block, the needle's curvature, the expected
        goal point (:meth:`expected_goal_point`), 3 steps per edge and the kinematic steering.

        Returns
        -------
        Needle3DSpace
            The planning space.
        """
        cfg = self.config
        return Needle3DSpace(
            size=np.asarray(cfg.size, dtype=np.float64),
            goal=np.concatenate([self.expected_goal_point(), np.zeros(9)]),
            radius=1.0 / cfg.curvature,
            steer=functools.partial(
                needle3d_steer, tau=cfg.tau, kappa=cfg.curvature, duty=cfg.duty_cycle
            ),
        )
