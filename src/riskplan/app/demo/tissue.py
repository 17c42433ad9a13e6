"""Demo stage "tissue": the two scenarios of the deformable-planning paper (Patil, van den
Berg & Alterovitz, RSS 2011, section V) simulated with the FEM models.

For each scenario: a control sequence from a greedy one-step-lookahead steering on the
nominal parameters (a demo helper, not the paper's RRT + LQG planner, which a later
stage adds), an animated GIF and a strip of frames of its execution, and a table of
open-loop outcomes of the same controls under each uncertainty case of section V-A
(final target-goal distance, goal reached, collision). Budget: ≤ 45 s on two cores.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from riskplan.app.report import Report
from riskplan.control.greedy import greedy_manipulation_controls, greedy_needle_controls

log = logging.getLogger(__name__)

NEEDLE_STEPS = 40
MANIP_STEPS = 14
NEEDLE_SAMPLES = 16  # parameter draws per uncertainty case
MANIP_SAMPLES = 5
MANIP_MESH_CAP = 400  # largest mesh drawn in the manipulation mesh case (keeps the stage short)


def open_loop_outcome(sim, controls, params) -> tuple[float, bool, bool]:
    """Run ``controls`` from the start under ``params``: (final goal distance, ended in
    the goal, collided at some step). A failed solve counts as a collision-free failure."""
    from riskplan.errors import ConvergenceError, ElementInversionError

    state = sim.initial_state(params)
    collided = False
    try:
        for u in controls:
            state = sim.step(state, u, params)
            collided = collided or sim.in_collision(state)
    except (ConvergenceError, ElementInversionError) as exc:
        log.warning("tissue demo: solve failed (%s)", exc)
        return float("nan"), False, collided
    return sim.goal_distance(state), bool(sim.in_goal(state)), collided


def _frames_figure(sim, states, n: int = 4):
    import matplotlib.pyplot as plt

    from riskplan.scenarios.plotting import draw_frame, frame_indices

    idx = frame_indices(len(states), n)
    fig, axes = plt.subplots(1, len(idx), figsize=(3.2 * len(idx), 3.4))
    for ax, k in zip(np.atleast_1d(axes), idx):
        draw_frame(ax, sim, states, k)
    fig.tight_layout()
    return fig


def _case_table(sim, controls, n_samples: int, seed: int, cap_mesh: int | None = None):
    from riskplan.parallel import spawn_seeds
    from riskplan.scenarios.uncertainty import CASE_NAMES, get_case

    rows = []
    case_seeds = spawn_seeds(seed, len(CASE_NAMES))
    for j, name in enumerate(CASE_NAMES):
        kw = {"actuation_cov": sim.actuation_cov()} if hasattr(sim, "actuation_cov") else {}
        dist = get_case(name, sim.nominal_params, **kw)
        draws = dist.sample_many(1 if name == "nominal" else n_samples, seed=case_seeds[j])
        if cap_mesh is not None:
            draws = [d.replace(n_elements=min(d.n_elements, cap_mesh)) for d in draws]
        res = [open_loop_outcome(sim, controls, d) for d in draws]
        dist_ = np.array([r[0] for r in res])
        ok = [r[1] and not r[2] for r in res]
        rows.append(
            [
                name,
                len(res),
                float(np.nanmean(dist_)),
                float(np.nanstd(dist_)),
                f"{sum(r[1] for r in res)}/{len(res)}",
                f"{sum(r[2] for r in res)}/{len(res)}",
                f"{sum(ok)}/{len(res)}",
            ]
        )
    return rows


HEADER = ["case", "draws", "mean final dist.", "sd", "in goal", "collided", "success"]


def _scenario_section(
    report: Report,
    out: Path,
    sim,
    title: str,
    controls,
    describe,
    n_samples: int,
    seed: int,
    caption: str,
    cap_mesh: int | None = None,
):
    """Run ``controls`` on the nominal parameters, show the GIF, frames and the per-case table."""
    from riskplan.scenarios.base import rollout
    from riskplan.scenarios.plotting import save_gif

    sec = report.section(title)
    p0 = sim.nominal_params
    states = rollout(sim, sim.initial_state(p0), controls, p0)
    gif = save_gif(sim, states, out / f"tissue_{sim.name}.gif")
    Report.text(sec, describe(p0, states))
    report.image(sec, gif, f"{sim.name} execution (animated GIF)")
    report.figure(
        sec,
        _frames_figure(sim, states),
        f"tissue_{sim.name}_frames",
        f"frames of the {sim.name} execution",
    )
    rows = _case_table(sim, controls, n_samples, seed, cap_mesh=cap_mesh)
    Report.table(sec, HEADER, rows, caption=caption)


def run(report: Report, ctx: dict, *, seed: int, workers: int | None) -> None:
    from riskplan.scenarios.manipulation import ManipulationScenario
    from riskplan.scenarios.needle import NeedleScenario

    out = Path(ctx["out"])
    t0 = time.perf_counter()
    needle = NeedleScenario()
    u = greedy_needle_controls(needle, needle.nominal_params, NEEDLE_STEPS)

    def needle_text(p0, states):
        return (
            f"Car without reverse (v ≤ 0.5, |φ| ≤ π/3, τ = 0.1, r_min = 0.25) pushing a linear-elastic unit square "
            f"(E = 50, ν = 0.4, {needle.mesh_data(p0.n_elements).mesh.n_elements} triangles, corners fixed) with a unit force "
            f"along its heading; obstacles (grey) and goal (green) are embedded in the tissue and move with it. Controls: "
            f"greedy simulator lookahead on the nominal parameters ({len(u)} steps; a demo helper, not the paper's planner). "
            f"Final distance to the deformed goal centre {needle.goal_distance(states[-1]):.3f}, "
            f"in goal: {needle.in_goal(states[-1])}, collision: {any(needle.in_collision(s) for s in states)}."
        )

    _scenario_section(
        report,
        out,
        needle,
        "Deformable tissue: needle in a deformable plane (Patil et al. 2011, V-A)",
        u,
        needle_text,
        NEEDLE_SAMPLES,
        seed,
        "the same controls executed open loop under each uncertainty case (section V-A)",
    )
    t_needle = time.perf_counter() - t0
    ctx["tissue_needle_controls"] = u

    t0 = time.perf_counter()
    manip = ManipulationScenario()
    um = greedy_manipulation_controls(manip, manip.nominal_params, MANIP_STEPS)

    def manip_text(p0, states):
        return (
            f"Neo-Hookean object (E = 50, ν = 0.4, {manip.mesh_data(p0.n_elements).mesh.n_elements} triangles), bottom-right "
            f"edge fixed, three manipulators (red) pushing with forces |F_i| ≤ {manip.config.f_max} per component (changed by at most {manip.config.df_max} per step) spread over "
            f"boundary patches; the target (blue) should reach the goal (green) while the object avoids the obstacle (grey). "
            f"Only the black boundary points are sensed. Controls: resolved-rate steering with finite-difference Jacobians on the simulator ({len(um)} steps). "
            f"Final target-goal distance {manip.goal_distance(states[-1]):.3f}, "
            f"collision: {any(manip.in_collision(s) for s in states)}."
        )

    _scenario_section(
        report,
        out,
        manip,
        "Deformable tissue: internal point manipulation (Patil et al. 2011, V-B)",
        um,
        manip_text,
        MANIP_SAMPLES,
        seed,
        f"open-loop outcomes under each uncertainty case (mesh case capped at {MANIP_MESH_CAP} elements in the demo)",
        cap_mesh=MANIP_MESH_CAP,
    )
    t_manip = time.perf_counter() - t0
    log.info("tissue demo: needle %.1f s, manipulation %.1f s", t_needle, t_manip)
