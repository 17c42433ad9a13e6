"""``riskplan reproduce``: both papers' evaluations as one resumable command
(:mod:`riskplan.app.reproduce.pipeline`)."""

from __future__ import annotations

from pathlib import Path

import typer

from riskplan.commands._shared import workers_option


def _echo_robot_risk(rr) -> None:
    """One line for the ``robot-risk`` stage's summary (``None``: the stage did not run)."""
    if rr is None:
        return
    typer.echo(
        f"mdn robot risk ({rr['scale']}, {100 * rr['share_band']:.0f} % of items in 5-95 %): "
        + "; ".join(
            f"{rr[k]['label']} mae "
            + ("n/a" if rr[k]["mae_band"] is None else f"{100 * rr[k]['mae_band']:.1f}")
            + f" points, Brier {rr[k]['brier']:.3f}"
            for k in rr["risks"]
        )
    )


def register(app: typer.Typer) -> None:
    @app.command()
    def reproduce(
        paper: str = typer.Option("all", help="mdn | deformable | all."),
        scale: str = typer.Option(
            "smoke", help="smoke (minutes) | paper (the papers' sizes; hours)."
        ),
        backend: str = typer.Option("local", help="serial | local (process pool) | ray."),
        address: str = typer.Option(
            None,
            "--address",
            help="Ray cluster address (host:port, ray://host:port or auto); with --backend ray.",
        ),
        workers: int = workers_option(),
        seed: int = typer.Option(0, min=0, help="Master seed."),
        stage: list[str] = typer.Option(
            ["figures"],
            "--stage",
            help="figures (the papers' figures) | calibration (LQG-MP predicted vs measured "
            "success; deformable paper; calibration-needle / calibration-manipulation: one scenario) "
            "| sensitivity (the needle's Fig. 6 against noise and "
            "force scales) | needle3d (the 3-D needle: candidates, LQG-MP estimators, "
            "executions, interactive figure) | control-variants (LQG against the UKF and "
            "iLQR on the selected RRT plans) | robot-risk (chest risks from the learned model "
            "against the robot's collision rates; MDN paper). Repeat to run several.",
        ),
        calibration_scale: str = typer.Option(
            None,
            "--calibration-scale",
            help="smoke | reduced | full (default: smoke with --scale smoke, full with --scale paper).",
        ),
        robot_risk_scale: str = typer.Option(
            None,
            "--robot-risk-scale",
            help="smoke | reduced | full (default: smoke with --scale smoke, full with --scale paper).",
        ),
        out: Path = typer.Option(
            Path("reproduce-out"),
            "--out",
            "-o",
            help="Output folder (an existing one is continued).",
        ),
    ) -> None:
        """Reproduce the papers' figures and claims; writes OUT/results.json and OUT/report.html.

        Rerunning the same command continues from OUT/store and gives the same results.json.
        """
        from riskplan.app.reproduce.deformable import highest_verdict
        from riskplan.app.reproduce.pipeline import reproduce as run
        from riskplan.commands._shared import progress_bar

        with progress_bar() as bar:
            tasks: dict = {}

            def progress(stage: str, done: int, total: int) -> None:
                if stage not in tasks:
                    tasks[stage] = bar.add_task(stage, total=total, status="")
                bar.update(tasks[stage], completed=done, total=total)

            results = run(
                out,
                paper=paper,
                scale=scale,
                backend=backend,
                ray_address=address,
                workers=workers or None,
                seed=seed,
                progress=progress,
                stages=tuple(stage),
                calibration_scale=calibration_scale,
                robot_risk_scale=robot_risk_scale,
            )
        for name, sc in results.get("deformable", {}).items():
            cal = sc.get("calibration")
            if cal is not None and cal.get("rows"):
                typer.echo(
                    f"{name} calibration ({len(cal['rows'])} plan-case pairs): "
                    + "; ".join(
                        f"{e} mae {cal[e]['mae']:.3f} rho "
                        + (
                            "undefined"
                            if cal[e]["spearman"] is None
                            else f"{cal[e]['spearman']:.2f}"
                        )
                        for e in cal.get(
                            "estimators", ("sigma", "truncation", "sampling", "disturbance")
                        )
                    )
                    + f"; measured spread {cal['sigma']['measured_spread']:.3f}"
                )
            if "claims" not in sc:
                continue
            cl = sc["claims"]
            typer.echo(
                f"{name}: mean success rrt {100 * cl['mean_rate']['rrt']:.1f} %, without selection "
                f"{100 * cl['mean_rate']['ours_no_select']:.1f} %, ours {100 * cl['mean_rate']['ours']:.1f} %; "
                f"ours highest in every case: {highest_verdict(cl)}"
            )
        f7 = results.get("mdn", {}).get("fig7")
        if f7 is not None:
            from riskplan.app.reproduce.paper_values import MDN

            c = f7["claims"]
            before, after = MDN["collision_before"]["value"], MDN["collision_after"]["value"]
            verdict = {True: "yes", False: "no", None: "not decided at this scale"}
            typer.echo(
                f"mdn Fig. 7: eq. 10 bound {100 * c['nominal']:.1f} % -> {100 * c['final']:.1f} % after "
                f"{c['iterations']} iterations (paper: about {100 * before:.0f} % -> below "
                f"{100 * after:.0f} % after {c['paper_iterations']}); below {100 * after:.0f} % after "
                f"{c['paper_iterations']}: "
                f"{verdict[c['below_after_paper_iterations']]}"
            )
        _echo_robot_risk(results.get("mdn", {}).get("robot_risk"))
        typer.echo(f"results: {Path(out) / 'results.json'}")
        typer.echo(f"report: {Path(out) / 'report.html'}")
