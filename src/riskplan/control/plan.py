"""The nominal plan shared by the simulator RRT, the linearisation, LQG and LQG-MP
(Patil, van den Berg & Alterovitz, RSS 2011, section IV-A).

A plan is the sequence ``(x*_0, u*_0, x*_1, ..., u*_{ℓ-1}, x*_ℓ)`` of reduced states and
controls, together with the full simulator states ``y*_0, ..., y*_ℓ`` it passes through, so
the linearisation can restart the simulation from ``y*_t`` and LQG-MP can read the deformed
obstacles and goal of ``y*_t``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_array
from riskplan.errors import InvalidInputError, SimulationError
from riskplan.scenarios.base import SimParams, frozen_array

__all__ = ["NominalPlan"]


@dataclass(frozen=True, eq=False)
class NominalPlan:
    """``(x*_0, u*_0, ..., x*_ℓ)`` plus the full simulator states ``y*_0 .. y*_ℓ`` (paper IV-A).

    Attributes
    ----------
    states:
        ``ℓ + 1`` simulator states (tuple), ``states[t] = y*_t``.
    controls:
        ``(ℓ, q)`` read-only, ``controls[t] = u*_t`` takes ``y*_t`` to ``y*_{t+1}``.
    reduced:
        ``(ℓ + 1, p)`` read-only, ``reduced[t] = x*_t = sim.reduced(states[t])``.
    params:
        The :class:`~riskplan.scenarios.base.SimParams` the plan was simulated with.
    """

    states: tuple
    controls: np.ndarray
    reduced: np.ndarray
    params: SimParams

    def __post_init__(self):
        states = tuple(self.states)
        controls = frozen_array(self.controls)
        reduced = frozen_array(self.reduced)
        if controls.ndim != 2:
            raise InvalidInputError(
                f"controls: expected a (ℓ, q) array, got shape {controls.shape}"
            )
        n = controls.shape[0]
        if len(states) != n + 1:
            raise InvalidInputError(
                f"states: expected ℓ + 1 = {n + 1} states for {n} controls, got {len(states)}"
            )
        if reduced.ndim != 2 or reduced.shape[0] != n + 1:
            raise InvalidInputError(f"reduced: expected shape ({n + 1}, p), got {reduced.shape}")
        if not isinstance(self.params, SimParams):
            raise InvalidInputError(f"params: expected SimParams, got {type(self.params).__name__}")
        object.__setattr__(self, "states", states)
        object.__setattr__(self, "controls", controls)
        object.__setattr__(self, "reduced", reduced)

    def __setstate__(self, state: dict) -> None:
        for k, v in state.items():
            if isinstance(v, np.ndarray):
                v.setflags(write=False)
            object.__setattr__(self, k, v)

    @property
    def n_steps(self) -> int:
        """ℓ, the number of controls."""
        return int(self.controls.shape[0])

    @classmethod
    def from_rollout(
        cls, sim, initial_state, controls, params: SimParams | None = None
    ) -> NominalPlan:
        """Simulate ``controls`` from ``initial_state`` and store every state.

        Parameters
        ----------
        sim : Simulator
            The simulator.
        initial_state : object
            The start state ``y_0``.
        controls : array_like
            ``(ℓ, q)`` controls.
        params : SimParams, optional
            The parameters (default ``sim.nominal_params``).

        Returns
        -------
        NominalPlan
            The plan with ``ℓ + 1`` states.

        Raises
        ------
        SimulationError
            Naming the step at a non-finite reduced state.
        """
        params = sim.nominal_params if params is None else params
        u = as_array(controls, "controls", shape=(None, sim.control_dim))
        states = [initial_state]
        xs = [np.asarray(sim.reduced(initial_state), dtype=np.float64)]
        for t in range(u.shape[0]):
            states.append(sim.step(states[-1], u[t], params))
            x = np.asarray(sim.reduced(states[-1]), dtype=np.float64)
            if not np.all(np.isfinite(x)):
                raise SimulationError(
                    f"from_rollout: non-finite reduced state after step {t} (control {t})"
                )
            xs.append(x)
        return cls(states=tuple(states), controls=u, reduced=np.stack(xs), params=params)

    def reframed(self, sim) -> NominalPlan:
        """The same plan (states, controls, parameters) with ``reduced`` recomputed by ``sim.reduced``.

        For a simulator whose reduced state is another frame of the same states
        (:meth:`riskplan.scenarios.needle.NeedleScenario.with_frame`).

        Parameters
        ----------
        sim : Simulator

        Returns
        -------
        NominalPlan
        """
        xs = np.stack([np.asarray(sim.reduced(y), dtype=np.float64) for y in self.states])
        return NominalPlan(
            states=self.states, controls=self.controls, reduced=xs, params=self.params
        )
