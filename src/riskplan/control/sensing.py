"""Measurements along an execution: the noise-free measurements of a plan and one noisy
reading of the true state.

A simulator that senses the full state (``measure(state, noise=, rng=)``: the needle in its
material frame, where the sensed world position depends on the tissue's deformation) is read
through it; any other through ``observe`` of its reduced state.
"""

from __future__ import annotations

import numpy as np

from riskplan.control.plan import NominalPlan

__all__ = ["nominal_measurements", "sense"]


def nominal_measurements(sim, plan: NominalPlan, measure) -> list[np.ndarray]:
    """The noise-free measurements ``z*_1 .. z*_T`` of the plan's states.

    Parameters
    ----------
    sim : Simulator
        The scenario (``observe``, ``obs_dim``).
    plan : NominalPlan
        The plan; its full ``states`` are read when ``measure`` is given, else ``reduced``.
    measure : callable or None
        The simulator's full-state measurement ``measure(state, noise=, rng=)``, or ``None``.

    Returns
    -------
    list of numpy.ndarray
        ``T`` arrays ``(obs_dim,)``.
    """
    zeros = np.zeros(sim.obs_dim)
    T = plan.n_steps
    if measure is not None:
        return [
            np.asarray(measure(plan.states[t + 1], noise=zeros), dtype=np.float64) for t in range(T)
        ]
    return [
        np.asarray(sim.observe(plan.reduced[t + 1], noise=zeros), dtype=np.float64)
        for t in range(T)
    ]


def sense(sim, measure, y, x: np.ndarray, gen) -> np.ndarray:
    """One noisy measurement of the true state.

    Parameters
    ----------
    sim : Simulator
        The scenario.
    measure : callable or None
        The full-state measurement, or ``None`` to read ``sim.observe(x)``.
    y : object
        The simulator's full state.
    x : numpy.ndarray
        ``(p,)`` its reduced state.
    gen : numpy.random.Generator
        The execution's generator (the measurement noise is drawn from it).

    Returns
    -------
    numpy.ndarray
        ``(obs_dim,)`` the measurement.
    """
    if measure is not None:
        return np.asarray(measure(y, rng=gen), dtype=np.float64)
    return np.asarray(sim.observe(x, rng=gen), dtype=np.float64)
