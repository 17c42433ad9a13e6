"""The ``riskplan`` command.

Each area registers its subcommands from ``riskplan/commands/<area>.py``; those
modules import only typer at import time and the heavy libraries inside each
command, so ``riskplan --help`` stays fast.
"""

from __future__ import annotations

import importlib
import json
import logging
import os
from pathlib import Path

import typer

from riskplan.commands._shared import workers_option

app = typer.Typer(
    name="riskplan",
    help="Risk-aware motion planning for medical robots.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,
)

# Areas in pipeline order. Each module defines ``register(app: typer.Typer) -> None``.
AREAS = ("robot", "dataset", "kinematics", "collision", "tissue", "plan", "reproduce", "study")
# Benchmarks: ``riskplan.bench.<area>.run(quick: bool) -> dict`` (``-`` in an area name is ``_``
# in the module name: ``planning-tissue`` -> ``riskplan.bench.planning_tissue``).
BENCH_AREAS = (
    "robot",
    "kinematics",
    "collision",
    "tissue",
    "control",
    "planning",
    "planning-tissue",
    "reproduce",
)


def _setup_threads() -> None:
    # torch and SciPy share few cores; one thread each is faster here (see docs/architecture.md).
    from riskplan.threads import limit_process_threads

    limit_process_threads(1)
    os.environ.setdefault("MPLBACKEND", "Agg")
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")


def _print_version(value: bool) -> None:
    if value:
        from riskplan import __version__

        typer.echo(f"riskplan {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log diagnostics to stderr."),
    version: bool = typer.Option(
        False,
        "--version",
        callback=_print_version,
        is_eager=True,
        help="Print the version and exit.",
    ),
    max_memory: str = typer.Option(
        None,
        "--max-memory",
        help="Work budget: memory one request may hold (e.g. 64G; default the smaller of 16G "
        "and the machine's memory). Requests over it are refused before any work.",
    ),
    max_hours: float = typer.Option(
        None,
        "--max-hours",
        help="Work budget: hours one request may need at least (default 24). Requests over it "
        "are refused before any work.",
    ),
) -> None:
    _setup_threads()
    from riskplan import budget

    # the environment carries the ceilings to worker processes too
    if max_memory is not None:
        os.environ[budget.MEMORY_ENV] = str(budget.parse_bytes(max_memory, "--max-memory"))
    if max_hours is not None:
        if not (max_hours > 0 and max_hours < float("inf")):
            from riskplan.errors import InvalidInputError

            raise InvalidInputError(f"--max-hours: expected a positive number, got {max_hours}")
        os.environ[budget.TIME_ENV] = repr(float(max_hours))
    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )


@app.command()
def demo(
    out: Path = typer.Option(
        Path("demo-out"), "--out", "-o", help="Folder for report.html and figures."
    ),
    seed: int = typer.Option(0, min=0, help="Master seed."),
    workers: int = workers_option(),
) -> None:
    """Run the main job on embedded defaults and write OUT/report.html."""
    from riskplan.app.demo.pipeline import run_demo
    from riskplan.commands._shared import output_folder, progress_bar

    with output_folder(out), progress_bar() as bar:
        task = bar.add_task("demo", total=None, status="starting")

        def progress(done, total, stage, seconds):
            if seconds is None:
                bar.update(
                    task,
                    completed=done,
                    total=total,
                    description=f"demo: {stage}",
                    status=f"stage {done + 1}/{total}",
                )
            else:
                bar.update(
                    task, completed=done, total=total, status=f"{stage} took {seconds:.0f} s"
                )

        path = run_demo(out, seed=seed, workers=workers or None, progress=progress)
    typer.echo(f"report: {path}")


@app.command()
def warm(
    workers: int = typer.Option(
        1, "--workers", min=1, help="Processes that compile at once (make uses 2)."
    ),
) -> None:
    """Compile the numba kernels into their on-disk cache (``make install`` runs this once)."""
    from riskplan.kernels import warm as warm_kernels

    times = warm_kernels(
        progress=lambda area: typer.echo(f"warming {area} kernels"), workers=workers
    )
    typer.echo(", ".join(f"{a} {t:.1f} s" for a, t in times.items()))


@app.command()
def bench(
    area: str = typer.Argument(..., help=f"One of: {', '.join(BENCH_AREAS)}."),
    json_out: bool = typer.Option(False, "--json", help="Print one JSON object of figures."),
    quick: bool = typer.Option(False, "--quick", help="Fewer repetitions (for smoke tests)."),
) -> None:
    """Measure the speed figures of one area."""
    if area not in BENCH_AREAS:
        raise typer.BadParameter(
            f"unknown area {area!r}; expected one of {', '.join(BENCH_AREAS)}", param_hint="AREA"
        )
    from riskplan.bench import machine_info  # threads: one each, set by _setup_threads

    mod = importlib.import_module(f"riskplan.bench.{area.replace('-', '_')}")
    figures = dict(mod.run(quick=quick))
    # every area's figures say where they were measured (read after the run: thread pools
    # are loaded by then)
    figures.setdefault("machine", machine_info())
    if json_out:
        typer.echo(json.dumps(figures))
    else:
        from rich.console import Console
        from rich.table import Table

        table = Table(title=f"riskplan bench {area}")
        table.add_column("figure")
        table.add_column("value", justify="right")
        for k, v in _flat_items(figures):
            table.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
        Console().print(table)


def _flat_items(d: dict, prefix: str = ""):
    """``(dotted key, value)`` pairs of a nested dict, for the bench table."""
    for k, v in d.items():
        if isinstance(v, dict):
            yield from _flat_items(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


for _area in AREAS:
    importlib.import_module(f"riskplan.commands.{_area}").register(app)


def main() -> None:
    from riskplan.errors import RiskplanError

    try:
        app()
    except RiskplanError as exc:
        typer.secho(f"error: {exc}", fg="red", err=True)
        raise SystemExit(2) from exc


if __name__ == "__main__":  # pragma: no cover
    main()
