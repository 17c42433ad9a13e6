"""`riskplan dataset ...` subcommands (heavy imports stay inside the commands).

* ``riskplan dataset generate --robot paper --preset small --out data.h5 [--split train|test|both]
  [--workers N] [--backend local|ray] [--seed S] [--overwrite]``; ``--preset`` also takes a
  custom protocol as JSON (``'{"grid_levels": 5, "n_train": 100, "n_test": 20, "n_starts": 4}'``)
* ``riskplan dataset info FILE [--json]``
* ``riskplan dataset import MANIFEST.csv --out data.h5 [--robot R] [--points N] [--scale S]``
* ``riskplan dataset export data.h5 --out DIR [--format npy|ply|pcd|csv]``
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

from riskplan.commands._shared import workers_option


def _get_preset(preset):
    """The data-set preset named ``preset`` (None if not a preset name)."""
    from riskplan.datasets import PRESETS

    return PRESETS.get(preset)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    from riskplan.commands._shared import add_group

    sub = add_group(
        app,
        "dataset",
        "Point-cloud data sets by the MDN paper's protocol (generate, inspect, import, export).",
    )
    _add_generate(sub)
    _add_info(sub)
    _add_import(sub)
    _add_export(sub)


def _add_generate(sub: typer.Typer):
    """Add ``generate`` to ``sub``; returns the command function."""

    @sub.command("generate")
    def generate(
        robot: str = typer.Option("paper", help="Robot name (paper) or TOML file."),
        preset: str = typer.Option(
            "small",
            help="Protocol: a preset (paper, small, tiny; adapted to the robot's tendon count, "
            "base rotation/retraction and tension limits, same number of configurations) or a "
            "custom protocol as JSON, e.g. "
            '\'{"grid_levels": 5, "n_train": 100, "n_test": 20, "n_starts": 4}\' '
            "(fields: name, grid_levels, n_train, n_test, n_starts, n_points, path_steps, "
            "split_seed, surface_spacing, limits; docs/datasets.md).",
        ),
        out: Path = typer.Option(
            Path("data.h5"), "--out", "-o", help="Output HDF5 file (a stem for --split both)."
        ),
        split: str = typer.Option(
            "both", help="train, test, or both (writes OUT_train.h5 and OUT_test.h5)."
        ),
        workers: int = workers_option(),
        backend: str = typer.Option("local", help="local (process pool), serial, or ray."),
        seed: int = typer.Option(
            0, min=0, help="Master seed of starts, hysteresis variation and camera noise."
        ),
        overwrite: bool = typer.Option(
            False,
            help="Replace existing output (the old file stays until the new one is complete).",
        ),
    ) -> None:
        """Generate a data set (resumable: rerun the same command after an interruption)."""
        import time

        from riskplan.commands._shared import progress_bar, stop_interrupted
        from riskplan.datasets import generate_dataset, split_paths
        from riskplan.datasets.protocol import protocol_for_robot, protocol_limits
        from riskplan.errors import InvalidInputError
        from riskplan.robots import load_robot

        if split not in ("train", "test", "both"):
            raise InvalidInputError(f"split: expected train, test or both, got {split!r}")
        rob = load_robot(robot)
        protocol = protocol_for_robot(preset, rob)
        protocol_limits(protocol, rob)  # a custom protocol's limits must fit the robot
        if protocol is not _get_preset(preset):
            typer.echo(
                f"protocol {protocol.name} for robot {rob.name} ({rob.n_config} configuration "
                f"variables): {protocol.grid_levels}-level grid, {protocol.n_train} + "
                f"{protocol.n_test} targets"
                + (f", limits {[list(r) for r in protocol.limits]}" if protocol.limits else "")
            )
        outputs = split_paths(out) if split == "both" else {split: out}
        t0 = time.perf_counter()
        with progress_bar() as bar:
            for sp, path in outputs.items():
                n = protocol.n_configs(sp)
                task = bar.add_task(
                    f"{sp} ({protocol.name})",
                    total=n,
                    status=f"{protocol.n_starts} starts x {protocol.n_points} pts",
                )

                def progress(done, total, task=task):
                    bar.update(task, completed=done, total=total)

                try:
                    result = generate_dataset(
                        rob,
                        protocol,
                        path,
                        split=sp,
                        seed=seed,
                        workers=workers or None,
                        backend=backend,
                        progress=progress,
                        overwrite=overwrite,
                    )
                except KeyboardInterrupt:
                    raise stop_interrupted(
                        bar,
                        f"finished configurations are kept in {path}.partial; rerun the same command to resume",
                    ) from None
                bar.update(task, status=f"-> {result}")
        typer.echo(
            f"done in {time.perf_counter() - t0:.1f} s: "
            + ", ".join(str(p) for p in outputs.values())
        )

    return generate


def _add_info(sub: typer.Typer):
    """Add ``info`` to ``sub``; returns the command function."""

    @sub.command("info")
    def info(
        file: Path = typer.Argument(..., help="Data-set HDF5 file."),
        as_json: bool = typer.Option(False, "--json", help="Print JSON."),
    ) -> None:
        """Summarise a data set: robot, protocol, configurations done/total, point spread."""
        from riskplan.datasets import summarize

        s = summarize(file)
        if as_json:
            typer.echo(json.dumps(s, indent=2))
            return
        from rich.console import Console
        from rich.table import Table

        t = Table(title=str(file), show_header=False)
        for k, v in s.items():
            if isinstance(v, dict):
                v = ", ".join(
                    f"{a}={b:.4g}" if isinstance(b, float) else f"{a}={b}" for a, b in v.items()
                )
            t.add_row(k, str(v))
        Console().print(t)

    return info


def _add_import(sub: typer.Typer):
    """Add ``import`` to ``sub``; returns the command function."""

    @sub.command("import")
    def import_(
        manifest: Path = typer.Argument(
            ...,
            help="CSV: config_id, start_id, file, d0..d{m-1} and/or tension0.., [start0..], [tip_x,tip_y,tip_z].",
        ),
        out: Path = typer.Option(Path("data.h5"), "--out", "-o", help="Data set to write (HDF5)."),
        robot: str = typer.Option(
            None, help="Robot name or TOML file (default: robot.toml beside the manifest)."
        ),
        points: int = typer.Option(
            None, "--points", min=1, help="Keep this many points of every cloud (seeded subset)."
        ),
        scale: float = typer.Option(
            1.0, "--scale", help="Cloud coordinates to metres (0.001 for millimetres)."
        ),
        seed: int = typer.Option(0, min=0, help="Seed of the --points subsets."),
        overwrite: bool = typer.Option(False, help="Replace an existing output file."),
    ) -> None:
        """Import measured point clouds (PLY, PCD, NPY, CSV) listed in a manifest as a data set.

        Every file is read and checked (finite, units, within the robot's reach, counts, targets
        within the limits) before the output is written; train and evaluate read the result.
        """
        from riskplan.datasets.exchange import import_dataset
        from riskplan.datasets.storage import load_dataset

        path = import_dataset(
            manifest,
            out,
            robot=robot,
            n_points=points,
            scale=scale,
            seed=seed,
            overwrite=overwrite,
        )
        ds = load_dataset(path)
        typer.echo(
            f"imported {ds.n_configs} configurations x {ds.n_starts} clouds x {ds.n_points} points -> {path}"
        )

    return import_


def _add_export(sub: typer.Typer):
    """Add ``export`` to ``sub``; returns the command function."""

    @sub.command("export")
    def export(
        file: Path = typer.Argument(..., help="Data-set HDF5 file."),
        out: Path = typer.Option(..., "--out", "-o", help="Folder to write."),
        fmt: str = typer.Option("npy", "--format", help="Cloud files: npy, ply, pcd or csv."),
        overwrite: bool = typer.Option(False, help="Replace an existing manifest in OUT."),
    ) -> None:
        """Write a data set as manifest.csv, robot.toml, dataset.json and one cloud file per
        configuration and start (`dataset import` reads it back bit for bit)."""
        from riskplan.datasets.exchange import export_dataset

        man = export_dataset(file, out, fmt=fmt, overwrite=overwrite)
        typer.echo(f"exported -> {man}")

    return export
