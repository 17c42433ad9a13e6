"""LQG against its variants on common random draws (issue item "beyond LQG"): the Kalman
filter against the UKF (:mod:`riskplan.control.ukf`), and the plan as given against the
plan re-optimised by iLQR (:mod:`riskplan.control.ilqr`) with a goal term pulling the
final goal point towards the goal centre.

Execution ``i`` of a case draws its parameters from seed ``(seed, i)`` and its sensing
noise from a fresh generator of the same seed for every variant, so the variants differ
only in the controller. The plan is the greedy nominal plan of the demo
(:mod:`riskplan.control.greedy`), not an RRT plan (the time the comparison had).
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["compare_variants"]


def _setup(scenario: str, case: str):
    from riskplan.control import NominalPlan
    from riskplan.control.greedy import greedy_manipulation_controls, greedy_needle_controls
    from riskplan.scenarios.registry import make_scenario

    sim = make_scenario(scenario, case)
    if scenario == "needle":
        u = greedy_needle_controls(sim, sim.nominal_params, 60, speed=0.8)
        r = sim.config.goal_radius
    else:
        u = greedy_manipulation_controls(sim, sim.nominal_params, 40)
        r = sim.config.goal_radius
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    p = plan.reduced.shape[1]
    goal = np.array(plan.reduced[-1])
    goal[:2] = sim.config.goal_center  # the goal disk's centre (reference frame)
    Qg = np.zeros((p, p))
    Qg[0, 0] = Qg[1, 1] = 10.0 / r**2
    return sim, plan, goal, Qg


def compare_variants(scenario: str, case: str, n: int, seed: int = 0) -> dict:
    """Success of LQG, LQG with the UKF and iLQR + LQG over ``n`` paired executions.

    Parameters
    ----------
    scenario : str
        ``"needle"`` or ``"manipulation"``.
    case : str
        The uncertainty case.
    n : int
        Executions per variant.
    seed : int
        Root seed.

    Returns
    -------
    dict
        Per variant: successes, outcome counts, controller set-up seconds, execution
        seconds; and the iLQR costs.
    """
    from riskplan.control import execute
    from riskplan.control.ilqr import tracking_controller

    sim, plan, goal, Qg = _setup(scenario, case)
    t0 = time.perf_counter()
    plan_l, ctrl_l, _ = tracking_controller(sim, plan, sim.distribution, controller="lqr")
    t1 = time.perf_counter()
    plan_i, ctrl_i, info = tracking_controller(
        sim, plan, sim.distribution, controller="ilqr", goal=goal, Q_goal=Qg, max_iter=3
    )
    t2 = time.perf_counter()
    variants = {
        "lqg": (plan_l, ctrl_l, "kalman", t1 - t0),
        "ukf": (plan_l, ctrl_l, "ukf", t1 - t0),
        "ilqr": (plan_i, ctrl_i, "kalman", t2 - t1),
    }
    out = {"ilqr_costs": info.costs.tolist(), "n": n, "T": plan.n_steps}
    outcomes = {k: [] for k in variants}
    secs = dict.fromkeys(variants, 0.0)
    for i in range(n):
        params = sim.distribution.sample(np.random.default_rng([seed, i, 0]))
        for k, (pl, c, est, _) in variants.items():
            s = time.perf_counter()
            ex = execute(
                sim,
                pl,
                c,
                params,
                seed=np.random.default_rng([seed, i, 1]),
                keep_states=False,
                estimator=est,
            )
            secs[k] += time.perf_counter() - s
            outcomes[k].append(ex.outcome)
    for k, (_, _, _, setup) in variants.items():
        o = np.array(outcomes[k])
        out[k] = {
            "successes": int((o == "success").sum()),
            "outcomes": {x: int((o == x).sum()) for x in set(outcomes[k])},
            "setup_s": setup,
            "execute_s": secs[k],
            "success_runs": (o == "success").tolist(),
        }
    return out
