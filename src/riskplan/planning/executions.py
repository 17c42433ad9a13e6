"""What one execution of the simulated robot receives: the transmission's draws and the
displacements they deliver (the execution protocol of :mod:`riskplan.planning.validate`).

A run draws a random start within the displacement limits (at rest there), its play widths
and zero offsets once (:meth:`~riskplan.robots.hysteresis.HysteresisModel.sample_run`), and
moves through the play operator; the robot receives ``clip(e_t + o, limits)``. Run ``i`` of a
call uses ``seeds[i]`` split into (start draw, transmission variation), exactly as
:func:`~riskplan.planning.validate.execute_on_robot` and the data generator draw them, so the
sampled-body risk (:class:`~riskplan.planning.risk.SampledBodyRisk`) and the robot's executions
share their draws for equal seeds.
"""

from __future__ import annotations

import numpy as np

__all__ = ["execution_displacements", "execution_draws"]


def execution_draws(robot, seeds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The transmission draws of the runs seeded by ``seeds`` (module docstring, steps 1-2).

    Parameters
    ----------
    robot : TendonRobot
        The robot (its displacement limits and ``[hysteresis]`` parameters).
    seeds : sequence of int
        One seed per run (length ``B``), split into the start draw and the run's variation.

    Returns
    -------
    tuple of numpy.ndarray
        ``(start, play, offset)``, each ``(B, m)`` [m]. Inputs are trusted.
    """
    from riskplan.datasets.protocol import random_starts
    from riskplan.robots.hysteresis import HysteresisModel

    lim = np.asarray(robot.displacement_limits, dtype=np.float64)
    model = HysteresisModel(robot)
    starts, plays, offsets = [], [], []
    for sd in seeds:
        c_start, c_run = np.random.SeedSequence(int(sd)).spawn(2)
        starts.append(random_starts(lim, 1, np.random.default_rng(c_start))[0])
        play, offset = model.sample_run(np.random.default_rng(c_run))
        plays.append(play)
        offsets.append(offset)
    return np.stack(starts), np.stack(plays), np.stack(offsets)


def execution_displacements(robot, trajectory, seeds=None, *, draws=None) -> np.ndarray:
    """Displacements the robot receives along a trajectory in given runs (module docstring, step 3).

    At rest at the run's start, then the play operator and the run's offset.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    trajectory : array_like
        ``(T, m)`` commanded displacements [m].
    seeds : sequence of int, optional
        One seed per run (length ``B``); ignored when ``draws`` is given.
    draws : tuple of numpy.ndarray, optional
        The runs' :func:`execution_draws` (computed once for many trajectories).

    Returns
    -------
    numpy.ndarray
        ``(B, T, m)`` effective displacements [m]. Inputs are trusted.
    """
    from riskplan.robots.hysteresis import play_operator

    traj = np.asarray(trajectory, dtype=np.float64)
    T, m = traj.shape
    lim = np.asarray(robot.displacement_limits, dtype=np.float64)
    e, play, offset = execution_draws(robot, seeds) if draws is None else draws
    B = len(e)
    eff = np.empty((B, T, m))
    for t in range(T):
        e = play_operator(e, np.broadcast_to(traj[t], (B, 1, m)), play)
        eff[:, t] = np.clip(e + offset, lim[:, 0], lim[:, 1])
    return eff
