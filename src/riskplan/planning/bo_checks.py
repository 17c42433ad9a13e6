"""The checks of :func:`riskplan.planning.optimise_trajectory`'s inputs before any work: the
trajectory against the displacement limits, and the optimiser's memory against the budget
(:mod:`riskplan.budget`)."""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array, check_range
from riskplan.errors import InvalidInputError

# configurations may leave the limits by this fraction of the range (interpolation round-off)
LIMIT_SLACK = 1e-9


def check_trajectory_limits(trajectory, limits) -> tuple[np.ndarray, np.ndarray]:
    """``trajectory (T >= 2, m)`` and ``limits (m, 2)`` checked: finite, ``lo < hi`` per
    tendon, every configuration inside the limits (to round-off). Returns float64 copies."""
    lim = as_array(limits, "limits", min_ndim=2)
    if lim.ndim != 2 or lim.shape[1] != 2 or lim.shape[0] < 1:
        raise InvalidInputError(f"limits: expected shape (m, 2), got {lim.shape}")
    if not np.all(lim[:, 1] > lim[:, 0]):
        i = int(np.flatnonzero(~(lim[:, 1] > lim[:, 0]))[0])
        raise InvalidInputError(
            f"limits: row {i} is {lim[i].tolist()}; expected low < high for every tendon"
        )
    traj = np.array(as_array(trajectory, "trajectory", min_ndim=2), dtype=np.float64)
    if traj.ndim != 2 or traj.shape[1] != lim.shape[0] or len(traj) < 2:
        raise InvalidInputError(
            f"trajectory: expected shape (T >= 2, {lim.shape[0]}), got {traj.shape}"
        )
    # interpolated trajectories may cross a limit by a rounding of the span
    slack = LIMIT_SLACK * (lim[:, 1] - lim[:, 0])
    check_range(traj, "trajectory", lim[:, 0] - slack, lim[:, 1] + slack)
    return traj, lim


def check_optimiser_budget(config, T: int, limits) -> None:
    """The optimiser's work against the budget (:mod:`riskplan.budget`): the candidates of one
    iteration (a few ``(n_candidates, m)`` arrays), the GP of the last iteration, whose kernel
    matrix over ``T + iterations`` configurations is held in memory, and the motion checks of
    a block of 16 candidates, each motion about the candidate box's diagonal
    (``2 radius`` of the limits' span) long, at ``resolution``."""
    from riskplan.budget import check_budget

    lim = np.asarray(limits, dtype=np.float64)
    m = lim.shape[0]
    check_budget(
        f"{config.n_candidates} candidates per iteration",
        "candidates",
        nbytes=8.0 * 4 * config.n_candidates * m,
    )
    n = float(T) + float(config.iterations)
    check_budget(
        f"{config.iterations} iterations (a GP over up to {n:.3g} configurations)",
        "iterations",
        nbytes=8.0 * 3 * n * n,
    )
    reach = 2.0 * config.radius * float(np.linalg.norm(lim[:, 1] - lim[:, 0]))
    states = 16 * 2 * (reach / config.resolution + 1)
    check_budget(
        f"motion checks at resolution {config.resolution:g} ({states:.3g} states per block)",
        "resolution",
        nbytes=states * MOTION_STATE_BYTES * m,
    )


#: memory of one configuration in a batched motion check, per tendon (the configuration and
#: the predicted mixture's arrays are larger; this is the least)
MOTION_STATE_BYTES = 8.0
