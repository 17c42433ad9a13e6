"""``report.html`` of ``riskplan reproduce``: every reproduced number beside the paper's
(:mod:`riskplan.app.reproduce.paper_values`), Fig. 6 as PNG (print) and interactive plotly
bars (explore), the single executions of Figs. 4, 5 and 7(c-f) as PNG; the MDN paper's
Figs. 4, 5, its timing and its Fig. 7 (PNG, with an interactive 3-D page)."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from riskplan.app.report import Report

__all__ = ["write_report"]


def _fmt(v, digits=1):
    return "n/a" if v is None else f"{v:.{digits}f}"


def _fig6_png(sc: dict):
    import matplotlib.pyplot as plt

    from riskplan.app.reproduce.deformable import METHOD_LABELS, METHODS

    cases = list(sc["cases"])
    fig, ax = plt.subplots(figsize=(9, 3.6))
    width = 0.8 / len(METHODS)
    x = np.arange(len(cases))
    for i, m in enumerate(METHODS):
        vals = [sc["cases"][c][m] for c in cases]
        if all(v is None for v in vals):
            continue
        r = np.array([100 * v["rate"] if v else np.nan for v in vals])
        lo = np.array([100 * (v["rate"] - v["low"]) if v else 0 for v in vals])
        hi = np.array([100 * (v["high"] - v["rate"]) if v else 0 for v in vals])
        ax.bar(x + (i - 1.5) * width, r, width, yerr=[lo, hi], capsize=2, label=METHOD_LABELS[m])
    ax.set_xticks(x, cases)
    ax.set_ylim(0, 105)
    ax.set_ylabel("successful executions [%]")
    ax.legend(fontsize=7, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.1), frameon=False)
    ax.set_title(
        f"{sc['scenario']}: {sc['cases'][cases[0]]['ours']['n']} executions per bar, 95 % Wilson intervals",
        fontsize=10,
    )
    return fig


def _fig6_plotly(sc: dict):
    import plotly.graph_objects as go

    from riskplan.app.reproduce.deformable import METHOD_LABELS, METHODS

    cases = list(sc["cases"])
    fig = go.Figure()
    for m in METHODS:
        vals = [sc["cases"][c][m] for c in cases]
        if all(v is None for v in vals):
            continue
        r = [100 * v["rate"] if v else None for v in vals]
        fig.add_bar(
            name=METHOD_LABELS[m],
            x=cases,
            y=r,
            error_y=dict(
                type="data",
                symmetric=False,
                array=[100 * (v["high"] - v["rate"]) if v else 0 for v in vals],
                arrayminus=[100 * (v["rate"] - v["low"]) if v else 0 for v in vals],
            ),
            customdata=[
                [v["successes"], v["n"], -1 if v["predicted"] is None else 100 * v["predicted"]]
                if v
                else [0, 0, -1]
                for v in vals
            ],
            hovertemplate="%{x}: %{y:.1f} %% (%{customdata[0]} of %{customdata[1]}); LQG-MP predicted %{customdata[2]:.1f} %%",
        )
    fig.update_layout(
        barmode="group", yaxis_title="successful executions [%]", title=f"Fig. 6, {sc['scenario']}"
    )
    return fig


def _feedback_table(sec, sc: dict) -> None:
    """Fig. 7(c-f) as rates: the selected plan open vs closed loop on the same draws
    (:mod:`riskplan.app.reproduce.feedback`), with the pairs that show the feedback's part."""
    fb = sc.get("feedback") or {}
    if not fb:
        return
    rows = []
    for s in fb.values():
        o, c, pr = s["open"], s["closed"], s["pairs"]
        rows.append(
            [
                s["caption"],
                f"{100 * o['rate']:.1f} [{100 * o['low']:.1f}, {100 * o['high']:.1f}]",
                f"{100 * c['rate']:.1f} [{100 * c['low']:.1f}, {100 * c['high']:.1f}]",
                f"{pr['closed_only']} / {pr['open_only']} / {pr['both']} / {pr['neither']}",
                f"{o['collided']} / {c['collided']}",
                f"{o['solver_failed']} / {c['solver_failed']}",
                f"{o['n']}",
            ]
        )
    Report.table(
        sec,
        [
            "condition",
            "open loop [%] (95 % Wilson)",
            "closed loop [%]",
            "only closed / only open / both / neither succeed",
            "collided open / closed",
            "solver failed open / closed",
            "executions",
        ],
        rows,
        caption="the selected plan of the condition's case without and with LQG feedback on the same "
        "parameter draws and sensing noise (the paper's Fig. 7(c-f) shows one pair each)",
    )


def _single_runs(report: Report, sec, name: str, store, sc: dict, seed: int) -> None:
    import matplotlib.pyplot as plt

    from riskplan.app.reproduce.deformable import SINGLE_RUNS, BlobStore, single_executions
    from riskplan.scenarios.plotting import draw_frame

    blobs = BlobStore(store)
    wanted = {case for _, scen, case, _, _ in SINGLE_RUNS if scen == name and case in sc["cases"]}
    pc = {}
    for case in wanted:
        ours = sc["cases"][case]["ours"]
        plans = blobs.get(f"fig6.{name}.plans.{ours['candidate_set']}")
        sel = blobs.get(
            f"fig6.{name}.select.{case}.{ours['candidate_set']}.{ours['candidate']:03d}"
        )
        if plans is None or sel is None:
            continue
        pc[case] = (plans[ours["candidate"]], sel["controller"])
    runs = single_executions(name, pc, seed=seed)
    for fig_name, r in runs.items():
        fig, axes = plt.subplots(1, 2, figsize=(8, 4))
        for ax, kind in zip(axes, ("open", "closed")):
            ex = r["open" if kind == "open" else "closed"]
            verdict = "success" if ex.success else ex.reason
            draw_frame(
                ax,
                r["sim"],
                list(ex.states),
                title=f"{'without' if kind == 'open' else 'with'} feedback: {verdict}",
            )
        report.figure(
            sec,
            fig,
            f"{name}_{fig_name}",
            f"{r['caption']}: the selected plan executed without (left) and with (right) LQG feedback.",
        )


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


def _calibration_section(rep: Report, cal: dict) -> None:
    """LQG-MP's predicted P(success) against measured closed-loop success
    (:mod:`riskplan.app.reproduce.calibration`): plot, metrics per estimator, every row."""
    from riskplan.app.reproduce.calibration import (
        CONTROLLER_OF,
        ESTIMATOR_LABELS,
        ESTIMATORS,
        calibration_figure,
    )

    name = cal["scenario"]
    sec = rep.section(f"LQG-MP calibration: {name} (beyond the paper)")
    size = cal["scale"]
    Report.text(
        sec,
        f"Rule (fixed in advance): {cal['rule']}. Cases: {', '.join(cal['cases'])}. "
        f"{size['n_executions']} closed-loop executions per plan, case and controller on common draws; "
        "sigma, truncation and sampling predict the paper's LQG controller, 'with disturbance state' "
        "predicts the disturbance-state controller, the material-frame estimators (needle) their "
        "own material-frame controllers; each is compared with its own controller's executions. "
        "Candidates whose linearisation failed: "
        + ", ".join(f"{c}: {k}" for c, k in cal["failed"].items())
        + ".",
    )
    if not cal["rows"]:
        Report.text(sec, "No candidate could be measured.")
        return
    rep.figure(
        sec,
        calibration_figure(cal),
        f"calibration_{name}",
        f"{name}: predicted vs measured P(success), 95 % Wilson intervals; the dashed line is the diagonal.",
    )
    ests = [e for e in ESTIMATORS if cal.get(e) is not None]
    rows = []
    for e in ests:
        m = cal[e]
        rows.append(
            [
                ESTIMATOR_LABELS[e],
                f"{m['mae']:.3f}",
                "undefined" if m["spearman"] is None else f"{m['spearman']:.2f}",
                m["n_plans"],
                f"{m['measured_spread']:.3f} ({m['measured_min']:.3f} – {m['measured_max']:.3f})",
                "yes" if m["informative"] else "no",
                "yes" if m["meets_goal"] else "no",
            ]
        )
    Report.table(
        sec,
        [
            "estimator",
            "mean abs. error",
            "Spearman ρ",
            "(case, plan) pairs",
            "measured spread (min – max)",
            "informative",
            "mae ≤ 0.05 and ρ ≥ 0.8",
        ],
        rows,
        caption="best estimator meeting the goal: "
        + (ESTIMATOR_LABELS[cal["best"]] if cal["best"] else "none"),
    )
    # one column per estimator, each controller's measured rate after its last estimator
    ctrl_names = {
        "lqg": "paper's LQG",
        "dist": "disturbance controller",
        "mat": "material-frame LQG",
        "matdist": "material-frame bias-state controller",
    }
    columns = []
    for i, e in enumerate(ests):
        columns.append(("p", e))
        k = CONTROLLER_OF[e]
        if i + 1 == len(ests) or CONTROLLER_OF[ests[i + 1]] != k:
            columns.append(("m", k))
    detail = []
    for r in cal["rows"]:
        row = [r["case"], f"{r['rank']} (#{r['candidate']})", f"{r['a_norm_max']:.3g}"]
        for kind, v in columns:
            if kind == "p":
                row.append(f"{r['predicted'][v]:.3f}")
            else:
                m = r["measured"][v]
                row.append(f"{m['rate']:.3f} [{m['low']:.3f}, {m['high']:.3f}]")
        detail.append(row)
    Report.table(
        sec,
        ["case", "σ rank (candidate)", "max ‖A_t‖₂ (paper's)"]
        + [
            ESTIMATOR_LABELS[v] if kind == "p" else f"measured, {ctrl_names[v]} [95 %]"
            for kind, v in columns
        ],
        detail,
        caption="every measured (case, plan): predicted P(success) beside the measured rate",
    )


def _needle3d_section(rep: Report, r: dict) -> None:
    """The 3-D needle (:mod:`riskplan.app.reproduce.needle3d`): the link to the interactive
    figure and the estimates against executions."""
    import html

    sec = rep.section("3-D needle under uncertainty (beyond the paper)")
    st = r["settings"]
    Report.text(
        sec,
        f"Case {st['case']}, {st['n_plans']} candidates of the simulator RRT on the "
        f"{st['n_elements']}-tetrahedron planning mesh, {st['check_runs']} closed- and open-loop "
        "executions per checked plan on common draws.",
    )
    sec.blocks.append(
        f'<p><a href="{html.escape(r["figure"])}">tissue block, obstacles, target, candidate '
        "plans and closed-loop executions of the selected plan (interactive 3-D view)</a></p>"
    )
    rows = []
    for row in r["rows"]:
        e = row["estimates"]
        rows.append(
            [row["index"], row["n_steps"], e["truncation"], e["per-step"], e["sigma"], e["sampling"],
             f"{row['closed']}/{row['n']}" if row["n"] else "-",
             f"{row['open']}/{row['n']}" if row["n"] else "-"]
        )  # fmt: skip
    Report.table(
        sec,
        [
            "plan",
            "steps",
            "truncation",
            "per-step",
            "sigma",
            "sampling",
            "closed loop",
            "open loop",
        ],
        rows,
        caption="LQG-MP P(success) by estimator (ranked by the truncation) and measured successes",
    )


def _sensitivity_section(rep: Report, sens: dict) -> None:
    """The needle's sensitivity tables (stage ``sensitivity``): each method's mean success
    over the five cases against the actuation-noise and interaction-force scales, and the
    other reading of the cases."""
    from riskplan.app.reproduce.deformable import METHOD_LABELS, METHODS

    sec = rep.section("Deformable-planning paper, needle: sensitivity (beyond the paper)")
    size = sens.get("scale", {})
    Report.text(
        sec,
        f"Fig. 6 of the needle for each variant at a reduced scale ({size.get('n_candidates')} "
        f"candidates per set, {size.get('n_executions')} executions per bar, "
        f"{size.get('lin_samples')} linearisation draws, {size.get('goal_samples')} LQG-MP goal "
        "samples). Actuation-noise scales act in case 3 only (our reading of the cases); the "
        "interaction-force scales change the plans and every case. Mean success over the five "
        "cases, in %.",
    )

    def row(label, means):
        return [label] + [
            "n/a" if means.get(m) is None else f"{100 * means[m]:.1f}" for m in METHODS
        ]

    rows = []
    for kind in ("actuation", "force"):
        for f, means in sorted(sens.get(kind, {}).items(), key=lambda kv: float(kv[0])):
            rows.append(row(f"{kind} ×{float(f):g}", means))
    if sens.get("actuation_everywhere"):
        rows.append(
            row("actuation noise in every case (the other reading)", sens["actuation_everywhere"])
        )
    Report.table(
        sec,
        ["variant"] + [METHOD_LABELS[m] for m in METHODS],
        rows,
        caption="each method's mean success over the five cases against the noise and force scales",
    )


def write_report(out, results: dict, store, timings: dict, *, seed: int = 0) -> Path:
    """Write ``out/report.html`` from ``results`` (see :func:`riskplan.app.reproduce.pipeline.reproduce`).
    Each part is rendered when present (``results["mdn"]`` may hold Fig. 7 only)."""
    import matplotlib

    matplotlib.use("Agg")

    from riskplan.app.reproduce.deformable import METHOD_LABELS, METHODS, highest_verdict
    from riskplan.app.reproduce.paper_values import DEFORMABLE, MDN

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

    for name, sc in results.get("deformable", {}).items():
        if "cases" not in sc:
            continue  # this run measured the calibration only
        sec = rep.section(f"Deformable-planning paper, Fig. 6: {name}")
        size = sc["scale"]
        sets = "; ".join(
            f"{s}: {n} (steps {', '.join(map(str, sc['plan_steps'][s]))})"
            for s, n in sc["candidates"].items()
        )
        Report.text(
            sec,
            f"RRT candidates per set — {sets} (paper: {DEFORMABLE['candidates']['value']}); "
            f"{size['n_executions']} executions per method and case (paper: "
            f"{DEFORMABLE['executions_per_case']['value']}).",
        )
        for m, why in sc["not_applicable"].items():
            Report.text(sec, f"{METHOD_LABELS[m]}: not applicable — {why}.")
        rep.figure(
            sec,
            _fig6_png(sc),
            f"fig6_{name}",
            f"Fig. 6 ({name}): percentage of successful executions.",
        )
        path = out / f"fig6_{name}.html"
        _fig6_plotly(sc).write_html(path, include_plotlyjs="directory", full_html=True)
        sec.blocks.append(
            f'<p><a href="{html.escape(path.name)}">Fig. 6 ({html.escape(name)}), interactive bars</a></p>'
        )
        rows = []
        for c, ms in sc["cases"].items():
            for m in METHODS:
                v = ms[m]
                if v is None:
                    rows.append([c, METHOD_LABELS[m], "n/a", "", "", "", ""])
                    continue
                rows.append(
                    [
                        c,
                        METHOD_LABELS[m],
                        f"{100 * v['rate']:.1f}",
                        f"[{100 * v['low']:.1f}, {100 * v['high']:.1f}]",
                        "-" if v["predicted"] is None else f"{100 * v['predicted']:.1f}",
                        f"{v['collided']} / {v['missed_goal']} / {v.get('left_tissue', 0)}"
                        f" / {v['solver_failed']}"
                        + "".join(
                            f" ({k}: {n})" for k, n in v.get("solver_failure_reasons", {}).items()
                        ),
                        f"{v['candidate_set']} #{v['candidate']}",
                    ]
                )
        Report.table(
            sec,
            [
                "case",
                "method",
                "success [%]",
                "95 % Wilson",
                "LQG-MP predicted [%]",
                "collided / missed goal / left tissue / solver failed (reason)",
                "plan",
            ],
            rows,
            caption="measured success rate beside LQG-MP's predicted P(success) of the executed plan",
        )
        tie_lines = [
            f"{c}, {METHOD_LABELS[m]}: {ms[m]['tie']}"
            for c, ms in sc["cases"].items()
            for m in METHODS
            if ms[m] is not None and ms[m].get("tie")
        ]
        if tie_lines:
            Report.text(sec, "Selection ties — " + "; ".join(tie_lines) + ".")
        mech = sc.get("mechanism") or {}
        if mech:
            Report.table(
                sec,
                ["case", "open loop", "closed loop", "both", "only open", "only closed", "neither"],
                [
                    [
                        c,
                        f"{v['open']}/{v['n']}",
                        f"{v['closed']}/{v['n']}",
                        v["both"],
                        v["only_open"],
                        v["only_closed"],
                        v["neither"],
                    ]
                    for c, v in mech.items()
                ],
                caption="mechanism: candidate 0 of our RRT executed without and with LQG feedback "
                "on the same draws (success counts; 'only closed': runs feedback rescued)",
            )
        cl = sc["claims"]
        Report.table(
            sec,
            ["claim (paper §V-A)", "paper", "measured"],
            [
                [
                    "ours highest in every case",
                    "yes",
                    highest_verdict(cl),
                ],
                [
                    "ours' interval above all others",
                    "'significantly higher'",
                    ", ".join(c for c, ok in cl["ours_separated"].items() if ok) or "in no case",
                ],
                [
                    "without LQG-MP vs RRT with deformations, percent points",
                    "+34",
                    _fmt(cl["no_select_vs_rrt"]["points"]),
                ],
                [
                    "without LQG-MP vs RRT with deformations, relative %",
                    "+34",
                    _fmt(cl["no_select_vs_rrt"]["relative"]),
                ],
                [
                    "without LQG-MP vs complete method, percent points",
                    "-17",
                    _fmt(cl["no_select_vs_ours"]["points"]),
                ],
                [
                    "without LQG-MP vs complete method, relative %",
                    "-17",
                    _fmt(cl["no_select_vs_ours"]["relative"]),
                ],
            ],
            caption="the paper's claims; it does not say whether its percentages are points or relative, so both readings",
        )
        _feedback_table(sec, sc)
        _single_runs(rep, sec, name, store, sc, seed)

    for sc in results.get("deformable", {}).values():
        if "calibration" in sc:
            _calibration_section(rep, sc["calibration"])
    sens = results.get("deformable", {}).get("needle", {}).get("sensitivity")
    if sens:
        _sensitivity_section(rep, sens)

    if "needle3d" in results:
        _needle3d_section(rep, results["needle3d"])

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
    return rep.write()
