"""``riskplan study ...``: the measurement runs behind figures in the docs that are not
``reproduce`` stages (the optimiser comparison, the disturbance state, LQG-MP against Monte
Carlo, the lab's task files, one scenario's Fig. 6 of the deformable paper). Each command parses its options, calls one function of
:mod:`riskplan.app.reproduce` and prints."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from riskplan.commands._shared import workers_option

app = typer.Typer(
    help="Measurement runs behind the docs' figures (beside `reproduce`).", no_args_is_help=True
)


@app.command("optimisers")
def optimisers(
    model: str = typer.Option("paper", help="Shipped model name or model file."),
    iterations: int = typer.Option(50, min=1, help="Iterations per optimiser run."),
    seeds: int = typer.Option(5, min=1, help="Runs (seeds 0..SEEDS-1) per optimiser."),
    workers: int = workers_option(),
    out: Path = typer.Option(Path("optimiser-comparison"), "--out", "-o", help="Output folder."),
) -> None:
    """The paper's Bayesian optimisation against the comparison optimisers (docs/planning.md)."""
    from riskplan.app.reproduce.optimiser_comparison import run_comparison

    typer.echo(
        run_comparison(
            out, model=model, iterations=iterations, seeds=seeds, workers=workers or None
        )
    )


@app.command("disturbance")
def disturbance(
    runs: int = typer.Option(200, min=1, help="Closed-loop executions per controller."),
    scenario: list[str] = typer.Option(
        ["needle", "manipulation"], "--scenario", help="Scenario (repeat for several)."
    ),
    workers: int = workers_option(default=2),
) -> None:
    """The paper's LQG, the disturbance state and open loop on the same draws, one JSON row
    per plan (docs/control.md)."""
    from riskplan.app.reproduce.disturbance import disturbance_rows

    for name in scenario:
        for row in disturbance_rows(name, n=runs, workers=workers or None):
            typer.echo(json.dumps(row))


@app.command("lqgmp-monte-carlo")
def lqgmp_monte_carlo(
    runs: int = typer.Option(1000, min=1, help="Monte Carlo executions per plan."),
    plan: list[str] = typer.Option(
        ["edge", "depth", "margin"], "--plan", help="Needle plan (repeat for several)."
    ),
) -> None:
    """LQG-MP's P(success) against Monte Carlo on greedy needle plans, one JSON row per plan
    (docs/control.md)."""
    from riskplan.app.reproduce.lqgmp_monte_carlo import needle_rows

    for name in plan:
        for row in needle_rows(n=runs, plan=name):
            typer.echo(json.dumps(row))


@app.command("lab-tasks")
def lab_tasks(
    folder: Path = typer.Argument(..., exists=True, file_okay=False, help="The lab's folder."),
) -> None:
    """The lab's task configurations against its voxel anatomy and its recorded tips
    (docs/robots.md)."""
    from riskplan.app.reproduce.lab_tasks import lab_task_report

    for line in lab_task_report(folder):
        typer.echo(line)


@app.command("fig6")
def fig6(
    scenario: str = typer.Argument(..., help="needle | manipulation"),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder (resumable: OUT/store)."),
    scale: str = typer.Option("smoke", help="smoke | paper: the counts of that scale."),
    disturbance: bool = typer.Option(
        False, help="The persistent-disturbance controller and its LQG-MP (beyond the paper)."
    ),
    candidates: int = typer.Option(None, min=1, help="Replace the scale's candidate count."),
    executions: int = typer.Option(None, min=1, help="Replace the scale's executions per bar."),
    workers: int = workers_option(),
    seed: int = typer.Option(0, help="Root seed."),
) -> None:
    """The deformable paper's Fig. 6 for one scenario, with timings (docs/reproduce.md):
    OUT/fig6_<scenario>.json and OUT/timings_<scenario>.json; prints the claims."""
    import time

    from riskplan.app.reproduce.deformable import run_one_scenario

    def progress(stage, done, total):
        typer.echo(f"{time.strftime('%H:%M:%S')} {stage}: {done}/{total}")

    res = run_one_scenario(
        scenario,
        out,
        scale_name=scale,
        disturbance=disturbance,
        candidates=candidates,
        executions=executions,
        workers=workers or None,
        seed=seed,
        progress=progress,
    )
    typer.echo(json.dumps(res["claims"], indent=1))


def register(root: typer.Typer) -> None:
    root.add_typer(app, name="study")
