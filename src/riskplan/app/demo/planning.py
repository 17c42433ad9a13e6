"""Demo stage "planning": PRM nominal trajectory and Bayesian optimisation of its collision
bound in the chest cavity (MDN paper section V, Figs. 6-7), at demo scale.

Uses ``ctx["model"]`` (the small MDN of the kinematics stage; skipped without one) and
``ctx["chest"]`` (the collision stage's chest; built if absent). Goal: the simulated tip
of the recess goal, :data:`~riskplan.planning.chest.DEFAULT_GOAL_TIP` (a demo model has its own
tip map, so the goal is searched by its tip); a small demo model may not reach it
within the tolerance, then the valid roadmap milestone whose predicted tip is closest to it is
the goal (the report says which). Budget: about 30 s on two cores (100 milestones, 10
iterations); the full-size figures are in docs/results.md.
"""

from __future__ import annotations

import logging

import numpy as np

from riskplan.app.report import Report
from riskplan.threads import one_torch_thread

log = logging.getLogger(__name__)

MILESTONES = 100
ITERATIONS = 10
CANDIDATES = 128


@one_torch_thread
def run(report: Report, ctx: dict, *, seed: int, workers: int | None) -> None:

    from riskplan.app.outputs.chest_plan import trace_figure, trajectories_plotly
    from riskplan.errors import PlanningError
    from riskplan.planning.bo import OptimiserConfig, optimise_trajectory
    from riskplan.planning.chest import DEFAULT_GOAL_TIP
    from riskplan.planning.prm import (
        MeanValidity,
        build_roadmap,
        goal_from_tip,
        interpolate_path,
        tip_positions,
    )
    from riskplan.planning.risk import ConfigurationBound, trajectory_risk

    sec = report.section(
        "Planning in the chest cavity: PRM + Bayesian optimisation (MDN paper section V, Fig. 7)"
    )
    model = ctx.get("model")
    if model is None:
        Report.text(sec, "Skipped: no learned kinematic model (the kinematics stage did not run).")
        return
    chest = ctx.get("chest")
    if chest is None:
        from riskplan.planning.chest_scene import build_chest

        chest = build_chest(seed)
    env = chest.base_environment
    validity = MeanValidity(model, env)
    rm = build_roadmap(validity, n_milestones=MILESTONES, seed=seed)
    start = np.clip(np.zeros(model.n_tendons), model.limits[:, 0], model.limits[:, 1])
    target = np.asarray(DEFAULT_GOAL_TIP)
    try:
        goal = goal_from_tip(rm, model, target, seed=seed)
        how = "its predicted tip is within 5 mm of the recess target"
    except PlanningError:
        d = np.linalg.norm(tip_positions(model, rm.vertices) - target, axis=-1)
        goal = rm.vertices[int(np.argmin(d))]
        how = f"the demo model does not reach the recess target; the milestone whose tip is closest ({d.min() * 1e3:.0f} mm) is the goal"
    bound = ConfigurationBound(model, env)
    nominal = interpolate_path(rm.shortest_path(start, goal))
    P0, p0 = trajectory_risk(bound, nominal)
    res = optimise_trajectory(
        nominal,
        bound,
        validity,
        model.limits,
        bounds=p0,
        seed=seed,
        config=OptimiserConfig(iterations=ITERATIONS, n_candidates=CANDIDATES),
    )
    Report.text(
        sec,
        f"Roadmap: {rm.describe()} (OMPL PRM; valid = every component mean in free space; motions checked every "
        f"{rm.resolution * 1e3:g} mm). Nominal trajectory: {len(nominal)} configurations from zero displacement to the goal "
        f"({how}). Bayesian optimisation, {ITERATIONS} iterations with {CANDIDATES} candidates each.",
    )
    Report.table(
        sec,
        ["trajectory", "eq. 10 bound"],
        [["nominal (PRM)", P0], ["optimised", res.bound]],
        caption=f"Relative reduction {100 * res.reduction:.1f} % in {ITERATIONS} iterations (paper: 15 % -> < 7 % in 50).",
    )
    report.figure(
        sec,
        trace_figure(res.trace),
        "planning_fig7",
        "Fig. 7: eq.-10 bound per iteration, with the paper's start and end values.",
    )
    report.plotly(
        sec,
        trajectories_plotly(
            chest.environment,
            model,
            {"nominal": nominal, "optimised": res.trajectory},
            chest.to_world,
            samples=30,
            seed=seed,
        ),
        "planning_chest_3d",
        "Mixtures along the nominal and optimised trajectories",
    )
    ctx["chest_plan"] = {
        "nominal": nominal,
        "optimised": res.trajectory,
        "nominal_bound": P0,
        "optimised_bound": res.bound,
    }
