"""The pool tasks of the deformable paper's Fig. 6 (:mod:`riskplan.app.reproduce.deformable`):
one candidate linearised and ranked under one case (:func:`evaluate_candidate`), a batch of
executions of several methods on common draws (:func:`execute_methods`,
:func:`execute_batch`), and the outcome counts of their rows (:func:`_outcome_counts`).

Module level, so process pools and Ray can pickle them; each task is a function of its
arguments only (its seeds included), so a batch run again gives the same rows bit for bit.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["evaluate_candidate", "execute_batch", "execute_methods"]


def evaluate_candidate(args):
    """``args = (sim, plan, lin_samples, goal_samples, seed)``: linearise one candidate under one case's S, LQG gains, LQG-MP (paper §IV-B..D), with
    :func:`riskplan.tissue_planning.select.evaluate_plan`. A candidate whose linearisation fails
    (the simulator's solve along it) gets ``P(success) = 0``, no controller, and its error.
    An optional sixth element ``disturbance`` (default ``False``) selects the
    persistent-disturbance controller and its LQG-MP (beyond the paper)."""
    from riskplan.errors import (
        ConvergenceError,
        ElementInversionError,
        NumericalError,
        SimulationError,
    )
    from riskplan.tissue_planning.select import evaluate_plan

    # NumericalError: LQG-MP's propagation or a point covariance of a degenerate linear model
    failures = (
        ConvergenceError,
        ElementInversionError,
        NumericalError,
        SimulationError,
        np.linalg.LinAlgError,
    )

    sim, plan, lin_samples, goal_samples, seed, *rest = args
    disturbance = bool(rest[0]) if rest else False
    with warnings.catch_warnings():
        # rank-deficient X_t along straight stretches is expected and documented by linearize
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            ctrl, res = evaluate_plan(
                sim,
                plan,
                sim.distribution,
                n_samples=lin_samples,
                n_goal_samples=goal_samples,
                seed=seed,
                disturbance=disturbance,
            )
        except failures as exc:
            return {
                "p_success": 0.0,
                "p_collision_free": 0.0,
                "p_goal": 0.0,
                "controller": None,
                "error": str(exc),
            }
    return {
        "p_success": float(res.p_success),
        "p_collision_free": float(res.p_collision_free),
        "p_goal": float(res.p_goal),
        "controller": ctrl,
        "error": None,
    }


def execute_batch(args) -> list[list]:
    """``args = (sim, plan, controller or None, seeds)``: one batch of executions:
    ``[[success, collided, reached_goal, solver_failed, left_tissue, reason], ...]`` (flags
    0/1; ``reason`` the solver's message for a solver failure, else ``None``;
    :func:`riskplan.control.lqg.execute`): :func:`execute_methods` with one run."""
    sim, plan, controller, seeds = args
    return execute_methods((sim, [(plan, controller)], seeds))[0]


def execute_methods(args) -> list[list[list]]:
    """``args = (sim, runs, seeds)`` with ``runs = [(plan, controller or None), ...]``: the
    executions of several methods on the same draws, draw by draw: for each seed the
    parameters ``s ~ S`` are drawn once and every run executes under them, so the FEM model
    (and, in the mesh case, the mesh) of a draw is built once for all methods instead of
    once per method. Returns one list per run, each as :func:`execute_batch` returns it
    for ``(sim, plan, controller, seeds)``, bit for bit (each execution is a function of
    its seed only)."""
    from riskplan.control.lqg import execute

    sim, runs, seeds = args
    out: list[list] = [[] for _ in runs]
    for s in seeds:
        for k, (plan, controller) in enumerate(runs):
            # a fresh generator per run: the sensing noise of each starts where the draw of
            # s leaves it, so that a run's executions do not depend on the other runs
            gen = np.random.default_rng(s)
            params = sim.distribution.sample(gen)
            ex = execute(sim, plan, controller, params, seed=gen, keep_states=False)
            out[k].append(
                [
                    int(ex.success),
                    int(ex.collided),
                    int(ex.reached_goal),
                    int(ex.outcome == "solver_failure"),
                    int(ex.left_tissue),
                    ex.error if ex.outcome == "solver_failure" else None,
                ]
            )
    return out


def _outcome_counts(rows: list) -> tuple[np.ndarray, dict]:
    """Flags ``(n, 5)`` int and the solver-failure reasons with their counts, from the rows
    of :func:`execute_batch`."""
    f = np.array([r[:5] for r in rows], dtype=np.int64).reshape(-1, 5)
    reasons: dict = {}
    for r in rows:
        if r[3] and r[5] is not None:
            # the step index varies; the reason is what follows it
            key = str(r[5]).split(": ", 1)[-1]
            reasons[key] = reasons.get(key, 0) + 1
    return f, reasons
