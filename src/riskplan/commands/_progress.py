"""Shared rich progress bar for long CLI jobs."""

from __future__ import annotations

from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)


def progress_bar(transient: bool = False) -> Progress:
    """A progress bar with count, elapsed and remaining time; use as a context manager."""
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[status]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        transient=transient,
    )


def stop_interrupted(bar: Progress, how_to_resume: str):
    """After Ctrl-C: stop ``bar``, say what was kept and how to resume, exit with status 130."""
    import typer

    bar.stop()
    typer.secho(f"interrupted: {how_to_resume}", fg="yellow", err=True)
    return typer.Exit(130)
