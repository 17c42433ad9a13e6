"""Calibration check of LQG-MP (issue 11, part 5; the deformable paper never reports it): for the
needle scenario, a plan (the tissue demo's greedy arc steering on the nominal parameters),
its LQG controller, the LQG-MP P(success) (sigma, truncation and sampling; the paper's
zero-mean model and with the drift carried), against the success rate of closed-loop and open-loop
executions on the true simulator with 95 % Wilson intervals, per uncertainty case.

Two plans (docs/control.md, "Calibration check"):

* ``"edge"``: full speed (``v = v_max``), stopped at the first state inside the goal — the
  plan ends on the goal's edge and leaves no speed to feedback;
* ``"depth"``: full speed, stopped at half the goal radius from the deformed goal centre
  (``depth = 0.5``);
* ``"margin"``: ``v = 0.8 v_max`` (a planning margin on the saturating control) and
  ``depth = 0.5``.

Controllers: the default Bryson weights of :func:`riskplan.control.lqg_controller`
(``closed``) and the identity weights ``Q = I``, ``R = I`` (``closed_identity``).

``python -m riskplan.app.reproduce.lqgmp_monte_carlo [n_runs] [edge|margin ...]`` prints one
JSON line per plan and case.
"""

from __future__ import annotations

import warnings

PLANS = {
    "edge": {"speed": 1.0, "depth": 0.0},
    "depth": {"speed": 1.0, "depth": 0.5},
    "margin": {"speed": 0.8, "depth": 0.5},
}


def needle_rows(
    cases=("nominal", "actuation", "material-high", "force"),
    n: int = 1000,
    seed: int = 1,
    plan: str = "margin",
    controllers=("closed", "closed_identity", "open"),
    backend: str = "serial",
    workers: int | None = None,
):
    """One dict per case: plan length, LQG-MP estimates (Bryson-weighted controller), and the
    rate with its 95 % interval of each of ``controllers`` (``closed``: Bryson weights,
    ``closed_identity``: ``Q = I, R = I``, ``open``: no feedback)."""
    import numpy as np

    from riskplan.control import NominalPlan, linearize, lqg_controller, lqgmp, monte_carlo_success
    from riskplan.control.greedy import greedy_needle_controls
    from riskplan.control.linearize import RankDeficiencyWarning
    from riskplan.errors import InvalidInputError
    from riskplan.scenarios.registry import make_scenario

    if plan not in PLANS:
        raise InvalidInputError(f"plan: expected one of {sorted(PLANS)}, got {plan!r}")
    rows = []
    for case in cases:
        sim = make_scenario("needle", case)
        u = greedy_needle_controls(sim, sim.nominal_params, 40, **PLANS[plan])
        nominal = NominalPlan.from_rollout(sim, sim.initial_state(), u)
        with warnings.catch_warnings():
            warnings.simplefilter(
                "ignore", RankDeficiencyWarning
            )  # the car's lateral direction (docs/control.md)
            lin = linearize(sim, nominal, sim.distribution, seed=0)
        ctrl = {
            "closed": lqg_controller(lin),
            "open": None,
            "closed_identity": lqg_controller(
                lin, Q=np.eye(lin.A.shape[1]), R=np.eye(lin.B.shape[2])
            ),
        }
        row = {"plan": plan, "case": case, "steps": nominal.n_steps}
        for method in ("sigma", "truncation", "sampling"):
            for drift in (False, True):
                r = lqgmp(sim, nominal, ctrl["closed"], method=method, drift=drift, seed=0)
                row[f"lqgmp_{method}{'_drift' if drift else ''}"] = round(r.p_success, 3)
        for name in controllers:
            mc = monte_carlo_success(
                sim,
                nominal,
                ctrl[name],
                sim.distribution,
                n=n,
                seed=seed,
                backend=backend,
                workers=workers,
            )
            row[name] = [round(mc.probability, 3), round(mc.low, 3), round(mc.high, 3)]
        rows.append(row)
    return rows
