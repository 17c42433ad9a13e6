"""The manipulation scenario's step (:mod:`riskplan.scenarios.manipulation`, module docstring):
the applied forces after a control (increments, actuator gain, actuation noise, saturation),
the quasi-static neo-Hookean equilibrium under them (Newton, warm-started from the previous
state or from a state near the answer), the memo of noise-free steps, and a state carried to
another mesh.

The functions take the scenario as ``self``:
:class:`~riskplan.scenarios.manipulation.ManipulationScenario` binds them as its methods
(``step``, ``step_near``, ``next_forces``, ``transfer_state``), documented there."""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from riskplan.errors import ConvergenceError, ElementInversionError
from riskplan.scenarios.base import SimParams, apply_actuation_noise, check_control
from riskplan.scenarios.manipulation_config import ManipulationState

# the scenario's methods: handed out by no package
__all__: list[str] = []

#: results of ``ManipulationScenario.step_near`` under parameters without actuation noise,
#: keyed by the scenario's configuration and every argument (least recently used dropped).
#: The step is a pure function of them, so a hit changes no result; it spares the
#: linearisation's control-perturbation runs for ``B_t``, which are the same under every
#: uncertainty case of a candidate (Fig. 6 linearises one candidate under five cases).
_STEP_MEMO: OrderedDict = OrderedDict()
_STEP_MEMO_SIZE = 512


def transfer_state(self, state: ManipulationState, params: SimParams) -> ManipulationState:
    """``state`` as a start on the mesh (and material) of ``params``: the same step index
    and applied forces, in equilibrium on that mesh.

    Exact: the equilibrium depends only on the applied forces (module docstring), so
    the body of the other mesh under the same forces is the state an execution on that
    mesh would be in. Solved from the undeformed body in one load step, or in
    :attr:`TRANSFER_LOAD_STEPS` if that fails. :func:`riskplan.control.linearize` uses
    it to run the mesh-size draws of ``M_t`` on their own meshes.

    Parameters
    ----------
    state : ManipulationState
        A state on any mesh.
    params : SimParams
        Their ``n_elements`` and material give the new mesh and equilibrium.

    Returns
    -------
    ManipulationState
    """
    out = self.initial_state(params)
    forces = np.asarray(state.forces, dtype=np.float64)
    disp = out.displacement
    if np.any(forces):
        try:
            disp = self._solve(forces, disp, params, state.t, 1)
        except (ConvergenceError, ElementInversionError):
            disp = self._solve(forces, disp, params, state.t, self.TRANSFER_LOAD_STEPS)
    return ManipulationState(t=state.t, displacement=disp, n_elements=out.n_elements, forces=forces)


def step(
    self, state: ManipulationState, control, params: SimParams | None = None
) -> ManipulationState:
    r"""``y_{t+1} = g(y_t, u_t, s)`` (paper eq. 1): the applied forces change by the
    increments ``control (6,)`` (× ``force_scale``, plus actuation noise if ``params``
    has some, saturated at ``±f_max``), then the quasi-static neo-Hookean equilibrium
    under the new forces, warm-started from ``state``.

    .. math::

        F_{t+1} = \operatorname{clip}(F_t + s_f (\Delta u_t + w_t), -f_{\max}, f_{\max}),
        \qquad f_{\mathrm{int}}(u_{t+1}) = W F_{t+1}

    Raises :class:`InvalidInputError` for a control outside the bounds or NaN,
    :class:`ElementInversionError` / :class:`ConvergenceError` (message says which
    step, which forces, which elements / what residual) if the solve fails.

    Parameters
    ----------
    state : ManipulationState
        ``y_t`` on the mesh of ``params``.
    control : array_like, shape (q,)
        Force increments ``Δu`` inside :attr:`control_bounds`.
    params : SimParams, optional
        ``s`` (default: the nominal parameters).

    Returns
    -------
    ManipulationState
        ``y_{t+1}``; ``state`` is not changed.
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
    another mesh) is :meth:`step`. Without actuation noise the result is memoised by
    the configuration and every argument (a pure function of them).

    Parameters
    ----------
    state : ManipulationState
        ``y_t``.
    control : array_like, shape (q,)
        Force increments ``Δu``.
    params : SimParams, optional
        ``s`` (default: the nominal parameters).
    near : ManipulationState, optional
        The state whose displacement starts the Newton solve.

    Returns
    -------
    ManipulationState
        ``y_{t+1}``.
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
    :meth:`step`).

    Parameters
    ----------
    state : ManipulationState
        ``y_t`` (its forces ``F_t`` and step index ``t``).
    control : numpy.ndarray, shape (q,)
        The increments ``Δu``.
    params : SimParams
        Their ``force_scale`` is ``s_f``; their actuation noise gives ``w_t``.

    Returns
    -------
    numpy.ndarray, shape (m, 2)
        ``F_{t+1}``, one row per manipulator.
    """
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
