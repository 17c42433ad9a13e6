"""Greedy nominal controls for the two tissue scenarios: short-horizon steering on the
simulator's nominal parameters, a quick plan to execute and linearise around (not the
paper's RRT + LQG planner, :mod:`riskplan.tissue_planning`).

Used by the demo, the LQG-MP Monte Carlo table and ``riskplan bench control``.
"""

from __future__ import annotations

import numpy as np

from riskplan.errors import InvalidInputError

__all__ = ["greedy_manipulation_controls", "greedy_needle_controls"]


def _margin(sim, state) -> float:
    """Clearance of the needle to the deformed obstacles (negative inside one)."""
    from riskplan.geometry2d import signed_distance_to_polygon

    p = state.pose[None, :2]
    return float(min(signed_distance_to_polygon(p, poly)[0] for poly in sim.obstacles(state)))


def greedy_needle_controls(
    sim,
    params,
    n_steps: int,
    clearance: float = 0.03,
    horizon: int = 8,
    speed: float = 1.0,
    depth: float = 0.0,
) -> np.ndarray:
    """Arc lookahead on the simulator: for 9 steering angles at ``speed · v_max`` (full speed by
    default; ``speed < 1`` leaves the feedback controller room to speed up), simulate
    ``horizon`` steps of that constant control; discard arcs that leave the tissue or come
    within ``clearance`` of a (deformed) obstacle, keep the one ending closest to the
    (deformed) goal centre, apply its first control, repeat; stop once in the goal. With
    ``depth > 0`` "in the goal" also asks for a distance to the deformed goal centre of at most
    ``(1 − depth) · goal_radius``, so the plan ends inside the goal instead of on its edge.

    Parameters
    ----------
    sim : NeedleScenario
        The 2-D needle simulator.
    params : object
        The simulator parameters to steer on (nominal).
    n_steps : int
        Most steps planned.
    clearance : float
        Least clearance [m] to a deformed obstacle along the lookahead arc; a closer arc costs
        ``100 (clearance − margin)``.
    horizon : int
        Lookahead steps of each constant-control arc.
    speed : float
        Insertion speed as a fraction of ``v_max``, in ``(0, 1]``.
    depth : float
        Fraction of the goal radius to end inside by, in ``[0, 1)``.

    Returns
    -------
    numpy.ndarray
        ``(T, 2)`` controls ``(v, φ)`` with ``T <= n_steps``.
    """
    lo, hi = sim.control_bounds[1]
    phis = np.linspace(lo, hi, 9)
    if not 0.0 < speed <= 1.0:
        raise InvalidInputError(f"speed: expected a fraction of v_max in (0, 1], got {speed!r}")
    if not 0.0 <= depth < 1.0:
        raise InvalidInputError(
            f"depth: expected a fraction of the goal radius in [0, 1), got {depth!r}"
        )
    v = speed * sim.control_bounds[0, 1]
    r_in = (1.0 - depth) * sim.config.goal_radius

    def arrived(st) -> bool:
        return sim.in_goal(st) and (depth == 0.0 or sim.goal_distance(st) <= r_in)

    state = sim.initial_state(params)
    out = []
    for _ in range(n_steps):
        best = None
        for phi in phis:
            st, margin, reached = state, np.inf, None
            for h in range(horizon):
                st = sim.step(st, [v, phi], params)
                margin = min(margin, _margin(sim, st) if sim.inside(st) else -1.0)
                if reached is None and arrived(st):
                    reached = h
            cost = (reached - horizon if reached is not None else sim.goal_distance(st)) + (
                100.0 * (clearance - margin) if margin < clearance else 0.0
            )
            if best is None or cost < best[0]:
                best = (cost, phi)
        out.append([v, best[1]])
        state = sim.step(state, out[-1], params)
        if arrived(state):
            break
    return np.array(out)


def greedy_manipulation_controls(
    sim, params, n_steps: int, max_move: float = 0.025, eps: float = 0.02
) -> np.ndarray:
    """Resolved-rate steering on the simulator: estimate the 2×6 Jacobian of the target
    position w.r.t. the force increments by forward differences
    (:func:`riskplan.control.linearize.control_jacobian`), take the minimum-norm increment
    (within its bounds) that moves the target up to ``max_move`` towards the goal, halve it
    while the object would touch the obstacle; stop once the target is in the goal.
    Returns the increments ``(T, 6)``.

    Parameters
    ----------
    sim : ManipulationScenario
        The 2-D manipulation simulator.
    params : object
        The simulator parameters to steer on (nominal).
    n_steps : int
        Most steps planned.
    max_move : float
        Longest target move [m] asked of one step.
    eps : float
        Forward-difference step of the Jacobian as a fraction of ``f_max``.

    Returns
    -------
    numpy.ndarray
        ``(T, 6)`` force increments, ``T <= n_steps``; ``(1, 6)`` zeros when the first step
        finds no move.
    """
    from riskplan.control.linearize import control_jacobian
    from riskplan.errors import ConvergenceError, ElementInversionError

    f_max = sim.config.f_max
    bounds = sim.control_bounds
    state = sim.initial_state(params)
    zero = np.zeros(sim.control_dim)
    goal = np.asarray(sim.config.goal_center)
    out = []
    for _ in range(n_steps):
        x0 = sim.target(state)
        # the target is x[:2]; the library's B_t machinery (paper IV-B) differentiates the
        # step (a zero increment keeps the current equilibrium)
        J = control_jacobian(
            sim,
            state,
            zero,
            params,
            np.full(sim.control_dim, eps * f_max),
            x_next=sim.reduced(state),
        )[:2]
        d = goal - x0
        d *= min(1.0, max_move / max(np.linalg.norm(d), 1e-12))
        step = np.linalg.lstsq(J, d, rcond=None)[0]
        nxt = None
        for _ in range(6):
            cand = np.clip(step, bounds[:, 0], bounds[:, 1])
            try:
                trial = sim.step(state, cand, params)
            except (ConvergenceError, ElementInversionError):
                step *= 0.5
                continue
            if not sim.in_collision(trial):
                nxt = (cand, trial)
                break
            step *= 0.5
        if nxt is None:
            break
        du, state = nxt
        out.append(du)
        if sim.in_goal(state):
            break
    return np.array(out) if out else np.zeros((1, sim.control_dim))
