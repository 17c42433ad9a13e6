"""``riskplan plan needle3d``: the 3-D bevel-tip needle in a tetrahedral tissue block —
simulator RRT candidates, LQG-MP selection in 3-D (Patil 2012 truncation), optional
closed/open-loop executions, and an interactive plotly figure."""

from __future__ import annotations

from pathlib import Path

import typer

from riskplan.commands._shared import workers_option


def register(plan_app: typer.Typer) -> None:
    """Add the ``needle3d`` command to the ``riskplan plan`` group."""

    @plan_app.command("needle3d")
    def needle3d(
        plans: int = typer.Option(10, "--plans", min=1, help="number of candidate plans"),
        case: str = typer.Option(
            "actuation",
            "--case",
            help="nominal | material-low | material-high | actuation | mesh | force",
        ),
        out: Path = typer.Option(..., "--out", help="output folder (npz, JSON, HTML)"),
        workers: int = workers_option("worker processes (0: one per core)"),
        seed: int = typer.Option(0, "--seed", min=0, help="master seed"),
        check_runs: int = typer.Option(
            0, "--check-runs", min=0, help="closed-loop executions per checked plan"
        ),
        open_runs: int | None = typer.Option(
            None,
            "--open-runs",
            min=1,
            help="open-loop executions on the first of the same draws, and the Wilson check "
            "on them (default: all --check-runs)",
        ),
        check_plans: int = typer.Option(
            6,
            "--check-plans",
            min=1,
            help="plans checked (the selected one and others spread over the ranking)",
        ),
        max_iterations: int = typer.Option(
            600, "--max-iterations", min=1, help="RRT iterations per tree"
        ),
        frame: str = typer.Option(
            "world",
            "--frame",
            help="reduced state of the controller and LQG-MP: world | material",
        ),
    ) -> None:
        """Plan the 3-D needle, select with LQG-MP, optionally check, write OUT/."""
        from rich.console import Console
        from rich.table import Table

        from riskplan.app.reproduce.needle3d import SUMMARY_HEADER, summary_rows, write_outputs
        from riskplan.commands._shared import output_folder
        from riskplan.io import check_output_folder
        from riskplan.tissue_planning.needle3d import plan_needle3d

        _check_choices(case, frame)
        check_output_folder(out, "--out")
        with output_folder(out):
            result = plan_needle3d(
                case,
                n_plans=plans,
                seed=seed,
                check_runs=check_runs,
                open_runs=open_runs,
                check_plans=check_plans,
                max_iterations=max_iterations,
                workers=workers or None,
                frame=frame,
            )
            files = write_outputs(result, out, seed=seed)
        t = result.timings
        console = Console(stderr=True)
        console.print(
            f"needle3d, case {case}: {len(result.plans)} candidates in {t['rrt_s']:.1f} s, "
            f"LQG-MP {t['selection_s']:.1f} s; selected #{result.best}"
        )
        table = Table(
            title="LQG-MP P(success) (truncation, per-step, sigma, sampling, particles) and executions"
        )
        for h in SUMMARY_HEADER:
            table.add_column(h, justify="right")
        for row in summary_rows(result):
            table.add_row(*row)
        Console().print(table)
        for name, path in files.items():
            typer.echo(f"{name}: {path}")


def _check_choices(case: str, frame: str) -> None:
    """``--case`` and ``--frame`` of ``plan needle3d``, checked before any work."""
    from riskplan.errors import InvalidInputError
    from riskplan.scenarios import FRAMES
    from riskplan.scenarios.uncertainty import CASE_NAMES

    if case not in CASE_NAMES:
        raise InvalidInputError(f"--case: expected one of {', '.join(CASE_NAMES)}, got {case!r}")
    if frame not in FRAMES:
        raise InvalidInputError(f"--frame: expected one of {', '.join(FRAMES)}, got {frame!r}")
