"""The persistent-disturbance state against the paper's LQG (beyond the paper;
docs/control.md, "Persistent disturbance"): per scenario, one plan (candidate 0 of the
smoke-scale Fig. 6 RRT, the plan "ours without selection" executes), and per uncertainty
case

* one linearisation with ``disturbance=True`` (its ``A``, ``B``, ``M`` are the paper's, so
  both controllers come from the same numbers);
* the paper's LQG controller (``plain``), the disturbance-state controller
  (``disturbance``) and open loop;
* their LQG-MP estimates (sigma, truncation, sampling) and ``n`` executions each on the
  same draws (:func:`riskplan.control.monte_carlo_success` with one seed: run ``i`` of every
  controller has the same parameters, actuation and sensing noise).

``python -m riskplan.app.reproduce.disturbance [n] [needle|manipulation ...]`` prints one JSON
line per scenario and case.
"""

from __future__ import annotations

import warnings

CONTROLLERS = ("open", "plain", "disturbance")


def smoke_plan(scenario: str, seed: int = 0, backend: str = "local", workers: int | None = None):
    """Candidate 0 of the smoke-scale Fig. 6 RRT of ``scenario`` (the plan of "RRT with
    deformations" and "ours without selection" in ``riskplan reproduce --scale smoke``)."""
    from riskplan.app.reproduce.deformable import SCALES, _seed_for
    from riskplan.scenarios.registry import make_scenario
    from riskplan.tissue_planning.rrt import rrt_plans

    base = make_scenario(scenario, "nominal")
    scale = SCALES["smoke"][scenario]
    plans, _ = rrt_plans(
        base,
        scale.n_candidates,
        seed=_seed_for(seed, scenario, "rrt", "deforming"),
        params=base.nominal_params,
        options=scale.rrt_options(),
        backend=backend,
        workers=workers,
    )
    return plans[0]


def disturbance_rows(
    scenario: str,
    cases=("material-low", "material-high", "actuation", "mesh", "force"),
    n: int = 200,
    seed: int = 1,
    n_samples: int = 16,
    n_goal_samples: int = 2000,
    backend: str = "local",
    workers: int | None = None,
):
    """One dict per case: the plan's length, ``trace Σ_d``, the share of the paper's process
    noise left in the residual (``Σ_t tr M^r_t / Σ_t tr M_t`` in Bryson-weighted units), the
    LQG-MP estimates of both controllers, and per controller ``[successes, n, low, high]``
    (95 % Wilson) with the solver failures."""
    import numpy as np

    from riskplan.control import linearize, lqg_controller, lqgmp, monte_carlo_success
    from riskplan.scenarios.registry import make_scenario

    plan = smoke_plan(scenario, backend=backend, workers=workers)
    rows = []
    for case in cases:
        sim = make_scenario(scenario, case)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # rank of X_t, docs/control.md
            lin = linearize(
                sim, plan, sim.distribution, n_samples=n_samples, seed=0, disturbance=True
            )
        ctrls = {
            "open": None,
            "plain": lqg_controller(lin),
            "disturbance": lqg_controller(lin, disturbance=True),
        }
        w2 = lin.disturbance.weights**2
        total = float(np.einsum("tii,i->", lin.M, w2))
        resid = float(np.einsum("tii,i->", lin.disturbance.M, w2))
        row = {
            "scenario": scenario,
            "case": case,
            "steps": plan.n_steps,
            "trace_sigma_d": float(np.trace(lin.disturbance.cov)),
            "residual_share": resid / total if total > 0 else None,
        }
        for name in ("plain", "disturbance"):
            for method in ("sigma", "truncation", "sampling"):
                r = lqgmp(
                    sim, plan, ctrls[name], method=method, n_goal_samples=n_goal_samples, seed=0
                )
                row[f"lqgmp_{name}_{method}"] = round(float(r.p_success), 3)
        for name in CONTROLLERS:
            mc = monte_carlo_success(
                sim,
                plan,
                ctrls[name],
                sim.distribution,
                n=n,
                seed=seed,
                backend=backend,
                workers=workers,
            )
            row[name] = [mc.successes, mc.n, round(mc.low, 3), round(mc.high, 3)]
            row[f"{name}_solver_failed"] = int(mc.solver_failed.sum())
        rows.append(row)
    return rows
