"""The deformable paper's sections of ``report.html`` (:mod:`riskplan.app.reproduce.report`):
Fig. 6 as PNG and interactive plotly bars, the single executions of Figs. 4, 5 and 7(c-f),
the feedback, calibration and sensitivity tables, and the 3-D needle's section."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from riskplan.app.report import Report

__all__ = ["deformable_sections"]


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


def _with_se(row: dict, method: str):
    """The estimate, with its Monte Carlo standard error and goal-test draws where recorded,
    or "(exact goal test)" where the goal test drew nothing (0 draws, an error bound)."""
    p = row["estimates"][method]
    se, n = row.get("estimate_se", {}).get(method), row.get("estimate_n", {}).get(method)
    if n == 0 and se is not None:
        return f"{p:.4f} (exact goal test)"
    return f"{p:.4f} ± {se:.4f} ({n:,} draws)" if se is not None and n else p


def _needle3d_section(rep: Report, r: dict) -> None:
    """The 3-D needle (:mod:`riskplan.app.reproduce.needle3d`): the link to the interactive
    figure and the estimates against executions."""
    import html

    from riskplan.tissue_planning.needle3d_checks import CHECK_POINTS

    sec = rep.section("3-D needle under uncertainty (beyond the paper)")
    st = r["settings"]
    Report.text(
        sec,
        f"Case {st['case']}, {st['n_plans']} candidates of the simulator RRT on the "
        f"{st['n_elements']}-tetrahedron planning mesh, {st['check_runs']} closed-loop "
        f"executions per checked plan and open-loop ones on the first "
        f"{st.get('open_runs') or st['check_runs']} of the same draws, the controller and "
        f"LQG-MP in the {st.get('frame', 'world')} frame. Checks: the truncation within ±2 "
        "points of all the closed-loop executions, and inside the 95 % Wilson interval of the "
        "first (the open loop's draws). Speed: CPU seconds of the truncation estimate "
        "(and with its linearisation) against those of all the closed-loop executions. The "
        "truncation's goal test is exact (a Gaussian in the target ellipsoid, by quadrature); "
        "where it draws instead, its ± is the standard error of the draws.",
    )
    sec.blocks.append(
        f'<p><a href="{html.escape(r["figure"])}">tissue block, obstacles, target, candidate '
        "plans and closed-loop executions of the selected plan (interactive 3-D view)</a></p>"
    )
    rows = []
    for row in r["rows"]:
        e, n = row["estimates"], row["n"]
        n_open = row.get("n_open") or n
        lo, hi = row.get("closed_ci", (0.0, 0.0))
        first_ci = row.get("closed_first_ci") or (lo, hi)
        first = row.get("closed_first", row["closed"]) if row.get("n_open") else row["closed"]
        cpu = row.get("estimate_cpu_s", {})
        speed = "-"
        if n and cpu.get("truncation"):
            speed = (
                f"{row['closed_cpu_s'] / cpu['truncation']:.0f}× "
                f"({row['closed_cpu_s'] / cpu['truncation+linearise']:.0f}×)"
            )
        rows.append(
            [row["index"], row["n_steps"], _with_se(row, "truncation"), e["per-step"], e["sigma"], e["sampling"],
             e.get("linear", "-"), _with_se(row, "particles") if "particles" in e else "-",
             f"{row['closed']}/{n} [{lo:.3f}, {hi:.3f}]" if n else "-",
             ("yes" if abs(e["truncation"] - row["closed"] / n) <= CHECK_POINTS else "no") if n else "-",
             f"{first}/{n_open} [{first_ci[0]:.3f}, {first_ci[1]:.3f}]" if n else "-",
             ("yes" if first_ci[0] <= e["truncation"] <= first_ci[1] else "no") if n else "-",
             f"{row['open']}/{n_open}" if n else "-", speed]
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
            "linear model",
            "particles",
            "closed loop [95 % Wilson]",
            "within ±2 points",
            "closed loop, first draws [95 % Wilson]",
            "inside",
            "open loop",
            "speed",
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


def _rates_table(sec, sc: dict) -> None:
    """Fig. 6's rates per case and method beside LQG-MP's predicted P(success)."""
    from riskplan.app.reproduce.deformable import METHOD_LABELS, METHODS

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


def _claims_table(sec, sc: dict) -> None:
    """The paper's claims (§V-A) beside the measured verdicts."""
    from riskplan.app.reproduce.deformable import highest_verdict

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


def _fig6_section(rep: Report, out: Path, name: str, sc: dict, store, seed: int) -> None:
    """Fig. 6 of one scenario: the bars (PNG and plotly), the rates beside LQG-MP's
    predictions, ties, the mechanism table, the paper's claims, the feedback table and the
    single executions."""
    from riskplan.app.reproduce.deformable import METHOD_LABELS, METHODS
    from riskplan.app.reproduce.paper_values import DEFORMABLE

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
    _rates_table(sec, sc)
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
    _claims_table(sec, sc)
    _feedback_table(sec, sc)
    _single_runs(rep, sec, name, store, sc, seed)


def deformable_sections(rep: Report, out: Path, results: dict, store, seed: int) -> None:
    """The deformable paper's sections of ``report.html`` (Fig. 6 per scenario, the
    calibration, the sensitivity study) and the 3-D needle's, each when ``results`` holds it."""
    for name, sc in results.get("deformable", {}).items():
        if "cases" in sc:  # else this run measured the calibration only
            _fig6_section(rep, out, name, sc, store, seed)

    for sc in results.get("deformable", {}).values():
        if "calibration" in sc:
            _calibration_section(rep, sc["calibration"])
    sens = results.get("deformable", {}).get("needle", {}).get("sensitivity")
    if sens:
        _sensitivity_section(rep, sens)

    if "needle3d" in results:
        _needle3d_section(rep, results["needle3d"])
