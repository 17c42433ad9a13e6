"""Honesty check of LQG-MP (issue 11, part 5; the deformable paper never reports it): for the
needle scenario, a plan (the tissue demo's greedy arc steering on the nominal parameters),
its LQG controller, the LQG-MP P(success) (sigma and truncation; the paper's zero-mean model
and with the drift carried), against the success rate of closed-loop and open-loop
executions on the true simulator with 95 % Wilson intervals, per uncertainty case.

``python -m riskplan.experiments.control_honesty [n_runs]`` prints one JSON line per case.
"""

from __future__ import annotations

import json
import sys
import warnings


def needle_rows(cases=("nominal", "actuation", "material-high", "force"), n: int = 1000, seed: int = 1):
    """One dict per case: plan length, LQG-MP estimates, closed/open-loop rate and interval."""
    from riskplan.control import NominalPlan, linearize, lqg_controller, lqgmp, monte_carlo_success
    from riskplan.control.linearize import RankDeficiencyWarning
    from riskplan.experiments.demo_tissue import greedy_needle_controls
    from riskplan.scenarios.registry import make_scenario

    rows = []
    for case in cases:
        sim = make_scenario("needle", case)
        plan = NominalPlan.from_rollout(sim, sim.initial_state(), greedy_needle_controls(sim, sim.nominal_params, 40))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RankDeficiencyWarning)  # the car's lateral direction (docs/control.md)
            lin = linearize(sim, plan, sim.distribution, seed=0)
        ctrl = lqg_controller(lin)
        row = {"case": case, "steps": plan.n_steps}
        for method in ("sigma", "truncation"):
            for drift in (False, True):
                r = lqgmp(sim, plan, ctrl, method=method, drift=drift, seed=0)
                row[f"lqgmp_{method}{'_drift' if drift else ''}"] = round(r.p_success, 3)
        for name, c in (("closed", ctrl), ("open", None)):
            mc = monte_carlo_success(sim, plan, c, sim.distribution, n=n, seed=seed)
            row[name] = [round(mc.probability, 3), round(mc.low, 3), round(mc.high, 3)]
        rows.append(row)
    return rows


if __name__ == "__main__":  # pragma: no cover - a command, measured in docs/control.md
    n_runs = int(sys.argv[1]) if len(sys.argv) > 1 else 1000
    for row in needle_rows(n=n_runs):
        print(json.dumps(row), flush=True)
