"""``report.html`` of ``riskplan reproduce``: every reproduced number beside the paper's
(:mod:`riskplan.app.reproduce.paper_values`), Fig. 6 as PNG (print) and interactive plotly
bars (explore), the single executions of Figs. 4, 5 and 7(c-f) as PNG; the MDN paper's
Figs. 4, 5, its timing and its Fig. 7 (PNG, with an interactive 3-D page)."""

from __future__ import annotations

import html
from pathlib import Path

from riskplan.app.report import Report
from riskplan.app.reproduce.report_deformable import deformable_sections

__all__ = ["write_report"]


def _pct(v, digits=2):
    return "n/a" if v is None else f"{100 * v:.{digits}f}"


def _fig7_section(rep: Report, out: Path, r: dict) -> None:
    """The MDN paper's Fig. 7: before/after trajectories, the bound per iteration, the claim."""
    from riskplan.app.reproduce.paper_values import MDN

    sec = rep.section("MDN paper: Fig. 7 (Bayesian optimisation of a chest-cavity path)")
    cl = r["claims"]
    Report.text(
        sec,
        f"Shipped model '{r['model']}', procedural chest (seed {r['chest_seed']}), PRM of "
        f"{r['roadmap']['milestones']} milestones, nominal trajectory of "
        f"{len(r['nominal']['configurations'])} configurations; {cl['iterations']} iterations of "
        f"Bayesian optimisation run (paper: {cl['paper_iterations']}), {r['evaluations']} eq. 9 "
        "evaluations. The paper's scene is a patient's CT scan with the physical robot; ours is "
        "the procedural chest with the simulated robot's model, so the start value is not expected "
        "to match; the claim is about the drop. Start and goal configurations never move: the goal's "
        f"own eq. 9 bound, {100 * r['optimised']['bounds_eq9'][-1]:.2f} %, is the lowest eq. 10 bound "
        "the optimiser can reach.",
    )
    rep.image(
        sec,
        out / r["figures"]["fig7"],
        "Fig. 7: eq. 9 bound along the trajectory before/after optimisation, and the best eq. 10 "
        "bound per iteration beside the paper's start and end values",
    )
    sec.blocks.append(
        f'<p><a href="{html.escape(r["figures"]["fig7_html"])}">Fig. 7, interactive 3-D view '
        "(mixtures along both trajectories in the chest)</a></p>"
    )
    verdict = {True: "yes", False: "no", None: "not decided (fewer iterations, not yet below)"}
    Report.table(
        sec,
        ["quantity", "paper", "measured"],
        [
            [
                "P(collision) bound of the nominal path [%]",
                f"about {100 * MDN['collision_before']['value']:.0f}",
                _pct(cl["nominal"]),
            ],
            [
                f"after {cl['iterations']} iterations (this run) [%]",
                "",
                _pct(cl["final"]),
            ],
            [
                f"after {cl['paper_iterations']} iterations [%]",
                f"< {100 * MDN['collision_after']['value']:.0f}",
                _pct(cl["at_paper_iterations"]),
            ],
            [
                "relative reduction [%]",
                f"> {100 * cl['paper_reduction_at_least']:.0f}",
                f"{100 * cl['reduction']:.1f}",
            ],
            [
                f"below {100 * MDN['collision_after']['value']:.0f} % after "
                f"{cl['paper_iterations']} iterations",
                "yes",
                verdict[cl["below_after_paper_iterations"]],
            ],
        ],
        caption="eq. 10 upper bound on the trajectory's probability of collision; the optimiser "
        "never raises it, so a run below the paper's end value in fewer iterations decides the claim",
    )
    rows = r.get("robot")
    if rows:
        Report.text(
            sec,
            "The mechanism on the robot: both trajectories executed on the simulated robot (random "
            "start, transmission play and offsets drawn per execution; the same executions for both "
            "trajectories), counting executions in which the body enters an obstacle at some "
            "configuration. 'Backbone + disks' is the body the MDN was trained on; the 10 mm tube "
            "contains it (conservative). The goal is the recess goal chosen on the robot model "
            "(docs/validation.md), free in the executions at start and goal.",
        )
        Report.table(
            sec,
            [
                "trajectory",
                "eq. 10 bound [%]",
                "MC of the MDN mixtures [%]",
                "robot, backbone + disks [%] (95 % Wilson)",
                "robot, 10 mm tube [%] (95 % Wilson)",
                "executions",
            ],
            [
                [
                    row["name"],
                    _pct(row["bound"]),
                    _pct(row["mixture_mc"]),
                    f"{_pct(row['robot_disks_mc'], 1)} [{_pct(row['robot_disks_low'], 1)}, "
                    f"{_pct(row['robot_disks_high'], 1)}]",
                    f"{_pct(row['robot_mc'], 1)} [{_pct(row['robot_low'], 1)}, "
                    f"{_pct(row['robot_high'], 1)}]",
                    row["n_robot"],
                ]
                for row in rows
            ],
            caption="Fig. 7 on the robot: collision rate before and after the optimisation",
        )


def write_report(out, results: dict, store, timings: dict, *, seed: int = 0) -> Path:
    """Write ``out/report.html`` from ``results`` (see :func:`riskplan.app.reproduce.pipeline.reproduce`).
    Each part is rendered when present (``results["mdn"]`` may hold Fig. 7 only)."""
    import matplotlib

    matplotlib.use("Agg")

    from riskplan.app.reproduce.paper_values import MDN

    out = Path(out)
    cfg = results["config"]
    rep = Report(
        out, title=f"riskplan reproduce ({cfg['paper']}, scale {cfg['scale']}, seed {cfg['seed']})"
    )
    intro = rep.section("About this run")
    Report.text(
        intro,
        "Every number below is computed by this run; the paper's value stands beside it where the paper "
        "states one. results.json holds all numbers; timings.json the wall-clock times.",
    )
    Report.table(
        intro,
        ["stage", "seconds"],
        [[k, float(v)] for k, v in sorted(timings.items()) if k.endswith("_s")],
        caption=f"wall-clock times (backend {timings.get('backend')}, workers {timings.get('workers') or 'all cores'})",
    )

    deformable_sections(rep, out, results, store, seed)

    if "sweep" in results.get("mdn", {}):
        r = results["mdn"]
        sec = rep.section("MDN paper: Figs. 4, 5 and the timing against the Cosserat model")
        Report.text(
            sec,
            f"Data: {r['train_configs']} training / {r['test_configs']} test configurations of the simulated "
            f"robot (paper: {MDN['train_configs']['value']} / 253 of the physical robot).",
        )
        rep.image(
            sec,
            out / r["figures"]["fig4"],
            "Fig. 4: test NLL against the number of mixture components K",
        )
        Report.table(
            sec,
            ["K", "test NLL [nats/point]", "collapsed components"],
            [
                [
                    e["k"],
                    "n/a" if e["test_nll"] is None else f"{e['test_nll']:.3f}",
                    ", ".join(map(str, e["collapsed"])) or "-",
                ]
                for e in r["sweep"]
            ],
            caption=f"recommended K = {r['recommended_k']} (paper: {MDN['fig4_best_k']['value']})",
        )
        rep.image(
            sec,
            out / r["figures"]["fig5"],
            "Fig. 5: samples of the predicted mixture vs ground-truth points",
        )
        sec.blocks.append(
            f'<p><a href="{html.escape(r["figures"]["fig5_html"])}">Fig. 5, interactive 3-D view</a></p>'
        )
        t = r["timing"]
        Report.table(
            sec,
            ["quantity", "paper", "measured"],
            [
                ["MDN, one configuration [ms]", MDN["mdn_ms"]["value"], f"{t['mdn_ms']:.3f}"],
                [
                    "Cosserat model, one configuration [ms]",
                    MDN["cosserat_ms"]["value"],
                    f"{t['cosserat_ms']:.3f}",
                ],
                ["reduction [%]", MDN["speedup_percent"]["value"], f"{t['reduction_percent']:.1f}"],
                ["test NLL (K = model's) [nats/point]", "plot only", f"{r['test_nll']:.3f}"],
            ],
            caption=f"timing over {t['configs']} (MDN) and {t['cosserat_configs']} (Cosserat) random configurations; "
            "the paper's Cosserat figure is from its ref. [8] (a C++ implementation), ours is riskplan's Python solver",
        )
    if "fig7" in results.get("mdn", {}):
        _fig7_section(rep, out, results["mdn"]["fig7"])
    if "robot_risk" in results.get("mdn", {}):
        from riskplan.app.reproduce.robot_risk import robot_risk_section

        robot_risk_section(rep, out, results["mdn"]["robot_risk"])
    return rep.write()
