"""Demo stage "planning_tissue": the deformable-planning method end to end on the needle
scenario (Patil, van den Berg & Alterovitz, RSS 2011, Fig. 2), at demo size.

A few simulator-RRT candidates (two trees), LQG-MP selection under the high material
variance case, the candidates with the chosen plan (paper Fig. 1b/1d), one closed-loop
execution as an animated GIF, and the LQG-MP estimate next to the success rate of
closed-loop executions (the check the paper does not report). Budget: ≤ 30 s on two
cores; ``riskplan plan tissue`` runs the full-size version (100 candidates, 1000 runs).
"""

from __future__ import annotations

import logging
from pathlib import Path

from riskplan.app.report import Report

log = logging.getLogger(__name__)

N_PLANS = 6
PLANS_PER_TREE = 3
CHECK_RUNS = 200
CASE = "material-high"


def run(report: Report, ctx: dict, *, seed: int, workers: int | None) -> None:
    import warnings

    from riskplan.app.outputs.tissue_plan import (
        CALIBRATION_HEADER,
        candidates_figure,
        execution_gif,
        summary_rows,
    )
    from riskplan.tissue_planning.plan import plan_tissue
    from riskplan.tissue_planning.rrt import RRTOptions

    out = Path(ctx["out"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = plan_tissue(
            "needle",
            n_plans=N_PLANS,
            case=CASE,
            seed=seed,
            workers=workers,
            rrt_options=RRTOptions(plans_per_tree=PLANS_PER_TREE),
            check_runs=CHECK_RUNS,
            check_others=1,
        )
    sel = res.selection
    best = sel.score(sel.best)
    sec = report.section(
        "Planning in deformable tissue: simulator RRT + LQG-MP (Patil et al. 2011, IV)"
    )
    Report.text(
        sec,
        f"{len(res.plans)} candidate plans from {len(res.trees)} simulator-RRT trees "
        f"({res.timings['rrt']:.1f} s; every node stores the full FEM state, collisions and the goal are checked "
        f"against the deformed tissue), linearised along each plan with LQR + Kalman gains and ranked by LQG-MP "
        f"under case '{CASE}' ({res.timings['selection']:.1f} s). Selected: candidate {sel.best}, {sel.plan.n_steps} "
        f"steps, LQG-MP P(success) = {best.p_success:.3f}.",
    )
    report.figure(
        sec,
        candidates_figure(res.sim, res.plans, sel.best),
        "planning_tissue_candidates",
        "candidates (grey) and the plan LQG-MP selects (orange), at the end of the selected plan",
    )
    gif, ex = execution_gif(
        res.sim,
        sel.plan,
        sel.controller,
        res.sim.sample_params(seed),
        out / "planning_tissue_execution.gif",
        seed=seed,
    )
    report.image(
        sec, gif, f"one closed-loop execution under a draw of '{CASE}' (success: {ex.success})"
    )
    Report.table(
        sec,
        CALIBRATION_HEADER,
        summary_rows(res),
        caption=f"LQG-MP estimate vs {CHECK_RUNS} closed-loop executions (95 % Wilson interval)",
    )
    ctx["planning_tissue"] = {"p_success": best.p_success, "timings": res.timings}
    log.info("planning_tissue demo: %s", res.timings)
