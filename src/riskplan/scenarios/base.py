"""The simulator seam of the deformable-planning method (Patil, van den Berg & Alterovitz,
RSS 2011, section III).

A scenario is a deterministic simulator ``g`` (paper eq. 1)

    y_{t+1} = g(y_t, u_t, s)

over full system states ``y`` (robot configuration, FEM displacement, applied loads, step
index), a map ``reduced(y) -> x`` to the low-dimensional state X the controller works with
(eq. 2 is ``x_{t+1} = f(x_t, u_t, s)`` built on ``g``), and a linear observation model
(eq. 3)

    z_t = h(x_t) + n_t = H x_t + n_t,      n_t ~ N(0, N).

Simulation parameters ``s`` (material, mesh, interaction force, actuation noise) are a
:class:`SimParams` value drawn from a distribution S (:mod:`riskplan.scenarios.uncertainty`).

Design points the planner and the linearisation rely on:

* States are frozen dataclasses whose arrays are read-only, so an RRT node can keep one
  and restart from it any number of times; ``step`` never mutates its input.
* ``step`` is a pure function of ``(state, control, params)``: actuation noise, when the
  parameters carry some, is drawn from a generator seeded by ``(params.actuation_seed,
  state.t)``, so the same triple always gives the bit-identical next state.
* FEM models (mesh, factorisation, interpolation weights) are cached per parameter set
  inside the scenario object, so thousands of steps from many stored states stay cheap.

This module imports no scenario; the scenarios import it. The parameters and full states
(:class:`SimParams`, :class:`SimState`, the actuation noise) are defined in
:mod:`riskplan.scenarios.values` and handed on from here. The name → scenario registry lives
in :mod:`riskplan.scenarios.registry`.
"""

from __future__ import annotations

import copy
from collections import OrderedDict
from typing import Protocol, runtime_checkable

import numpy as np

from riskplan._validation import as_array, as_generator, check_choice, check_range
from riskplan.errors import InvalidInputError

# the values a simulator passes (their home), handed on from here
from riskplan.scenarios.values import SimParams, SimState, actuation_noise, frozen_array

__all__ = [
    "FRAMES",
    "FEMScenario",
    "SimParams",
    "SimState",
    "Simulator",
    "actuation_noise",
    "apply_actuation_noise",
    "check_control",
    "frozen_array",
    "gaussian_noise",
    "rollout",
]


#: The frames a scenario's reduced state may be read in (``frame=``; the needles', the
#: module docstrings of :mod:`riskplan.scenarios.needle` and :mod:`riskplan.scenarios.needle3d`):
#: the world, or the tissue's material (reference) coordinates.
FRAMES = ("world", "material")


def with_frame(self, frame: str):
    """This scenario (same configuration, distribution and FEM caches) with the reduced
    state in ``frame`` (:data:`FRAMES`): a shallow copy with its ``frame`` set. The scenarios
    with frames (the needles) bind it as their method. Simulation, collision and goal tests
    are the same in both frames; what changes is what the controller and LQG-MP see (the
    scenario's ``reduced``, ``observation_jacobian``, ``state_obstacles``, ``state_goal``).
    Plans made in another frame follow with :meth:`riskplan.control.NominalPlan.reframed`.

    Parameters
    ----------
    frame : str
        ``"world"`` or ``"material"``.

    Returns
    -------
    Simulator
        A shallow copy of ``self`` (its type) reading ``x`` in ``frame``.
    """
    out = copy.copy(self)
    out.frame = check_choice(frame, FRAMES, "frame")
    return out


#: Per-process caches (models, meshes) shared by unpickled copies of one scenario
#: configuration (:meth:`FEMScenario.__setstate__`); at most this many configurations kept.
_SHARED_SCENARIOS = 8
_SHARED_CACHES: dict = {}


class FEMScenario:
    """Machinery shared by the FEM-backed scenarios: the parameter distribution S, per-mesh
    data (mesh, loads, interpolators) and a small LRU cache of FEM models.

    Subclasses set ``name`` and ``state_type`` and implement ``_make_mesh_data(n_elements)``
    and ``_make_model(params)``. Caches hold factorisations, which are not picklable and are
    cheap to rebuild, so a scenario sent to a worker process travels as its configuration only.
    """

    name: str = ""
    state_type: type = SimState

    def __init__(self, config, distribution=None, cache_size: int = 16):
        self.config = config
        self.distribution = distribution
        self._models: OrderedDict = OrderedDict()
        self._meshes: dict = {}
        self._cache_size = int(cache_size)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_models"] = OrderedDict()
        state["_meshes"] = {}
        state["_cache_key"] = self._content_key()
        return state

    def __setstate__(self, state):
        key = state.pop("_cache_key", None)
        self.__dict__.update(state)
        if key is not None:
            # copies of one scenario unpickled in the same process (the tasks a worker
            # receives) share its meshes and models: they are pure functions of the
            # configuration and the parameters, so sharing changes no result
            shared = _SHARED_CACHES.get(key)
            if shared is None:
                if len(_SHARED_CACHES) >= _SHARED_SCENARIOS:
                    _SHARED_CACHES.pop(next(iter(_SHARED_CACHES)))
                shared = _SHARED_CACHES[key] = (self._models, self._meshes)
            self._models, self._meshes = shared

    def _content_key(self) -> str:
        """SHA-256 of the pickled configuration and class: equal for copies of a scenario
        with the same configuration (computed once per object)."""
        key = self.__dict__.get("_key")
        if key is None:
            import hashlib
            import pickle

            blob = pickle.dumps(
                (type(self).__module__, type(self).__qualname__, self.config),
                protocol=pickle.HIGHEST_PROTOCOL,
            )
            key = self.__dict__["_key"] = hashlib.sha256(blob).hexdigest()
        return key

    @property
    def nominal_params(self) -> SimParams:
        """The planning parameters of ``distribution``, or (without one) the nominal
        :class:`SimParams` with the config's material (``youngs_modulus``, ``poissons_ratio``;
        the paper's E = 50, nu = 0.4 for a config without them), 175 elements, f_int = 1,
        no actuation noise."""
        if self.distribution is not None:
            return self.distribution.planning_params
        cfg = self.config
        return SimParams(
            youngs_modulus=getattr(cfg, "youngs_modulus", SimParams.youngs_modulus),
            poissons_ratio=getattr(cfg, "poissons_ratio", SimParams.poissons_ratio),
        )

    @property
    def goal_radius(self) -> float:
        """Radius of the (undeformed) goal disk, ``config.goal_radius``: what
        ``RRTOptions.goal_depth`` tightens (:class:`~riskplan.scenarios.space.PlanningScenario`)."""
        return float(self.config.goal_radius)

    def sample_params(self, seed=None) -> SimParams:
        """One draw ``s ~ S`` from ``distribution`` (the nominal parameters if there is none).

        Parameters
        ----------
        seed : int, numpy.random.Generator or None
            Seeds the draw.

        Returns
        -------
        SimParams
        """
        if self.distribution is None:
            return self.nominal_params
        return self.distribution.sample(seed)

    def mesh_data(self, n_elements: int):
        """Mesh, loads and interpolators for an element count (cached).

        Parameters
        ----------
        n_elements : int
            The requested element count (``SimParams.n_elements``).

        Returns
        -------
        object
            The scenario's per-mesh data (built on first use, then the same object).
        """
        d = self._meshes.get(n_elements)
        if d is None:
            d = self._meshes[n_elements] = self._make_mesh_data(n_elements)
        return d

    def model(self, params: SimParams | None = None):
        """The cached FEM model for ``params`` (built on first use, least recently used dropped).

        Parameters
        ----------
        params : SimParams, optional
            Default: :attr:`nominal_params`. Models are keyed by
            ``params.material_key = (E, ν, n_elements)``.

        Returns
        -------
        object
            The scenario's FEM model (a linear or neo-Hookean model of the tissue).
        """
        params = params or self.nominal_params
        key = params.material_key
        m = self._models.get(key)
        if m is None:
            m = self._models[key] = self._make_model(params)
            if len(self._models) > self._cache_size:
                self._models.popitem(last=False)
        else:
            self._models.move_to_end(key)
        return m

    def _make_mesh_data(self, n_elements: int):  # pragma: no cover - abstract
        raise NotImplementedError

    def _make_model(self, params: SimParams):  # pragma: no cover - abstract
        raise NotImplementedError

    def _check_state(self, state, params: SimParams) -> None:
        if not isinstance(state, self.state_type):
            raise InvalidInputError(
                f"state: expected a {self.state_type.__name__}, got {type(state).__name__}"
            )
        if state.n_elements != params.n_elements:
            raise InvalidInputError(
                f"state: lives on a {state.n_elements}-element mesh but params.n_elements = {params.n_elements}"
            )

    def _data(self, state):
        if not isinstance(state, self.state_type):
            raise InvalidInputError(
                f"state: expected a {self.state_type.__name__}, got {type(state).__name__}"
            )
        return self.mesh_data(state.n_elements)

    def _points(self, state) -> np.ndarray:
        return self._data(state).interp.positions(state.displacement)

    def deformed_nodes(self, state) -> np.ndarray:
        """Current node positions ``x = X + u``.

        Parameters
        ----------
        state : SimState
            A state of this scenario.

        Returns
        -------
        numpy.ndarray, shape (n_nodes, 2)
            Reference node positions plus ``state.displacement``.
        """
        return self._data(state).mesh.nodes + state.displacement


@runtime_checkable
class Simulator(Protocol):
    """What a planner, a linearisation and a Monte Carlo harness need from a scenario.

        Dimensions: ``control_dim`` = q (controls u), ``state_dim`` = p (reduced state x),
        ``obs_dim`` (measurements z).

    Optional members the control stage uses when present (:mod:`riskplan.control`):
    ``observation_matrix (m, p)`` and ``sensing_cov (m, m)`` (the linear observation model),
    ``collision_point_indices`` (``k`` pairs of indices of x that are 2-D points checked
    against obstacles; default ``((0, 1),)``), ``goal_point_indices`` (the pair checked
    against the goal; default ``(0, 1)``), ``obstacles(state)`` / ``goal(state)`` (deformed
    polygons), ``in_collision(state)`` / ``in_goal(state)``, ``state_scale (p,)`` (acceptable
    deviation of each component of x, the scale of the LQR's default Bryson weights),
    ``collision_outline(state)`` (the body's outline in ``state`` as points that move with
    interpolated deviations of the collision points, checked by LQG-MP instead of the bare
    points: :func:`riskplan.control.lqgmp.body_points`),
    ``a_prior`` (``"identity"`` or ``"zero"``: what :func:`riskplan.control.linearize` assumes
    for state directions its control perturbations cannot excite — a deviation that persists,
    or one the next step forgets; default ``"identity"``; or a method
    ``a_prior(y_next, params) -> (p, p)``, the exact structure of ``A_t`` at the plan's next
    state), ``a_max_rank`` (at most that many directions of the A-runs' deviations are
    fitted), ``transfer_state(state, params)``
    (``state`` as a start on the mesh of ``params``, so that ``linearize`` can run
    mesh-size draws of ``M_t`` on their own meshes), ``step_near(state, u, params, near)``
    (``step`` with the solver started from ``near``).
    """

    control_dim: int
    state_dim: int
    obs_dim: int

    @property
    def control_bounds(self) -> np.ndarray:
        """``(q, 2)`` array of ``[low, high]`` per control component."""
        ...

    @property
    def nominal_params(self) -> SimParams:
        """The parameters plans are made with (expected deformation, no noise)."""
        ...

    def initial_state(self, params: SimParams | None = None) -> SimState:
        """The start state ``y_0`` (undeformed tissue, robot at its start).

        Parameters
        ----------
        params : SimParams, optional
            Default: the nominal parameters.

        Returns
        -------
        SimState
        """
        ...

    def step(self, state: SimState, control, params: SimParams | None = None) -> SimState:
        """``y_{t+1} = g(y_t, u_t, s)`` (paper eq. 1); deterministic, never mutates ``state``.

        Parameters
        ----------
        state : SimState
        control : array_like, (q,)
            ``u_t`` within the control bounds.
        params : SimParams, optional
            ``s`` (default: the nominal parameters).

        Returns
        -------
        SimState
        """
        ...

    def reduced(self, state: SimState) -> np.ndarray:
        """The reduced state ``x (p,)`` of ``state`` (paper section III).

        Parameters
        ----------
        state : SimState

        Returns
        -------
        numpy.ndarray, (p,)
        """
        ...

    def observe(self, x, noise=None, rng=None) -> np.ndarray:
        """``z = h(x) + n`` (paper eq. 3).

        Parameters
        ----------
        x : array_like, (p,)
            Reduced state.
        noise : array_like, (r,), optional
            ``n`` given explicitly; else drawn with ``rng``, or zero without one.
        rng : numpy.random.Generator, optional

        Returns
        -------
        numpy.ndarray, (r,)
        """
        ...

    def sample_params(self, seed=None) -> SimParams:
        """One draw ``s ~ S`` from the scenario's parameter distribution.

        Parameters
        ----------
        seed : int, numpy.random.Generator or None

        Returns
        -------
        SimParams
        """
        ...


def rollout(
    sim: Simulator, state: SimState, controls, params: SimParams | None = None, *, on_step=None
) -> list[SimState]:
    """Apply controls from ``state``: ``y_{t+1} = g(y_t, u_t, s)`` for ``t = 0 .. T-1``.

    Parameters
    ----------
    sim : Simulator
    state : SimState
        ``y_0``.
    controls : array_like, (T, q)
    params : SimParams, optional
    on_step : callable, optional
        ``on_step(new_state)`` after each step (progress display).

    Returns
    -------
    list of SimState
        The ``T + 1`` states ``[y_0, ..., y_T]``.
    """
    u = as_array(controls, "controls", shape=(None, sim.control_dim))
    states = [state]
    for k in range(u.shape[0]):
        states.append(sim.step(states[-1], u[k], params))
        if on_step is not None:
            on_step(states[-1])
    return states


# --- helpers shared by the scenarios -------------------------------------------------------


def check_control(control, bounds: np.ndarray, name: str = "control") -> np.ndarray:
    """Validate a control against its box (finite, inside the bounds).

    Parameters
    ----------
    control : array_like, shape (q,)
        The control ``u``.
    bounds : numpy.ndarray, shape (q, 2)
        ``[low, high]`` per component.
    name : str, optional
        The argument's name in error messages.

    Returns
    -------
    numpy.ndarray, shape (q,)
        ``control`` as float64 (a copy when ``control`` is itself an array); raises
        :class:`~riskplan.errors.InvalidInputError` for a wrong shape, a NaN or a
        component outside its bounds.
    """
    try:
        u = np.asarray(control, dtype=np.float64)
    except (TypeError, ValueError):
        u = None
    # fast path (hot loop of planners): one shape test and one vectorised comparison,
    # which is False for NaN, so every failure takes the slow path with a full message
    if (
        u is not None
        and u.shape == (bounds.shape[0],)
        and ((bounds[:, 0] <= u) & (u <= bounds[:, 1])).all()
    ):
        return u.copy() if u is control else u
    u = as_array(control, name, shape=(bounds.shape[0],))
    check_range(u, name, bounds[:, 0], bounds[:, 1])
    return u  # pragma: no cover - check_range raised


def apply_actuation_noise(
    u: np.ndarray, params: SimParams, t: int, bounds: np.ndarray
) -> np.ndarray:
    """``clip(u + w_t, bounds)``: the control an actuator with noise actually applies.

    Clipping models saturation (e.g. a car without reverse cannot drive at negative
    speed, however noisy its actuation).

    Parameters
    ----------
    u : numpy.ndarray, (m,)
    params : SimParams
    t : int
    bounds : numpy.ndarray, (m, 2)

    Returns
    -------
    numpy.ndarray, (m,)
    """
    w = actuation_noise(params, t, u.shape[0])
    if w is None:
        return u
    return np.clip(u + w, bounds[:, 0], bounds[:, 1])


def gaussian_noise(cov: np.ndarray, noise, rng, dim: int, name: str = "noise") -> np.ndarray:
    """The measurement noise ``n ~ N(0, cov)``: given explicitly, drawn with ``rng``, or zero.

    The draw is NumPy's ``multivariate_normal(mean=0, cov, method="cholesky")`` bit for bit,
    with the transposed Cholesky factor ``Lᵀ`` (``L Lᵀ = cov``) computed once per covariance:

    .. math::

        n = L\\, \\xi, \\qquad \\xi \\sim \\mathcal{N}(0, I_{\\mathrm{dim}})

    Parameters
    ----------
    cov : array_like, shape (dim, dim)
        Positive-definite covariance ``N`` (used only when drawing).
    noise : array_like, shape (dim,), or None
        Explicit noise, returned as given (validated).
    rng : int, numpy.random.Generator or None
        Draws the noise when ``noise`` is ``None``.
    dim : int
        Dimension of the measurement.
    name : str, optional
        The argument's name in error messages.

    Returns
    -------
    numpy.ndarray, shape (dim,)
        ``noise``, a draw, or zeros when neither ``noise`` nor ``rng`` is given.
    """
    if noise is not None:
        return as_array(noise, name, shape=(dim,))
    if rng is None:
        return np.zeros(dim)
    gen = as_generator(rng)
    c = np.asarray(cov, dtype=np.float64)
    key = (c.shape, c.tobytes())
    factor = _CHOLESKY_T.get(key)
    if factor is None:
        if len(_CHOLESKY_T) >= 64:
            _CHOLESKY_T.clear()
        factor = _CHOLESKY_T[key] = np.linalg.cholesky(c).T
    # NumPy's multivariate_normal(method="cholesky") with the factor computed once per
    # covariance (a hot path of executions): the same draws and the same products, bit
    # for bit (tests/scenarios/test_base.py), and the generator left in the same state
    x = gen.standard_normal((1, dim)) @ factor
    x += np.zeros(dim)
    return x[0]


#: Transposed Cholesky factors of the sensing covariances seen (gaussian_noise).
_CHOLESKY_T: dict = {}
