"""`riskplan dataset ...` subcommands (heavy imports stay inside the commands).

* ``riskplan dataset generate --robot paper --preset small --out data.h5 [--split train|test|both]
  [--workers N] [--backend local|ray] [--seed S] [--overwrite]``
* ``riskplan dataset info FILE [--json]``
"""

from __future__ import annotations

import json
from pathlib import Path

import typer


def _outputs(out: Path, split: str) -> dict[str, Path]:
    """``--split both`` treats OUT as a stem: ``data.h5`` -> ``data_train.h5``, ``data_test.h5``."""
    if split != "both":
        return {split: out}
    stem = out.with_suffix("") if out.suffix == ".h5" else out
    return {sp: stem.with_name(f"{stem.name}_{sp}.h5") for sp in ("train", "test")}


def summarize(path) -> dict:
    """Summary of a data-set file: robot, protocol, configurations done, cloud and tip spread."""
    import numpy as np

    from riskplan.datasets import load_dataset
    from riskplan.errors import RiskplanError

    ds = load_dataset(path)
    done = ds.done
    summary = {
        "file": str(path),
        "robot": ds.metadata.get("robot_name"),
        "split": ds.metadata.get("split"),
        "seed": ds.metadata.get("seed"),
        "riskplan_version": ds.metadata.get("riskplan_version"),
        "created": ds.metadata.get("created"),
        "complete": ds.complete,
        "protocol": {k: v for k, v in ds.metadata["protocol"].items() if k != "cameras"},
        "n_cameras": len(ds.metadata["protocol"].get("cameras", [])),
        "configs_done": int(done.sum()),
        "configs_total": ds.n_configs,
        "points_shape": list(ds.points.shape),
    }
    if done.any():
        tips = ds.tips[done]
        spread = ds.tip_spread()[done]
        pts = ds.points[done].astype(np.float64)
        cen = pts.mean(axis=2)  # (C, S, 3) cloud centroids: their spread over the starts
        cen_rms = np.sqrt(((cen - cen.mean(axis=1, keepdims=True)) ** 2).sum(-1).mean(-1))
        summary.update(
            tip_spread_mm={
                "mean": float(spread.mean() * 1e3),
                "median": float(np.median(spread) * 1e3),
                "max": float(spread.max() * 1e3),
            },
            tip_range_m={
                "min": tips.reshape(-1, 3).min(0).tolist(),
                "max": tips.reshape(-1, 3).max(0).tolist(),
            },
            centroid_spread_mm={
                "mean": float(cen_rms.mean() * 1e3),
                "max": float(cen_rms.max() * 1e3),
            },
            bbox_m={
                "min": pts.reshape(-1, 3).min(0).tolist(),
                "max": pts.reshape(-1, 3).max(0).tolist(),
            },
        )
        try:
            tmax = np.asarray(ds.robot.tension_limits, dtype=np.float64)
            over = np.any(ds.tensions[done] > tmax * (1 + 1e-9), axis=-1)
            summary["arrivals_over_max_tension"] = float(over.mean())
        except (
            RiskplanError
        ) as exc:  # a robot file this version cannot rebuild must not stop the summary
            summary["arrivals_over_max_tension"] = f"unknown ({exc})"
    return summary


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    from riskplan.commands._shared import add_group

    sub = add_group(
        app, "dataset", "Point-cloud data sets by the MDN paper's protocol (generate, inspect)."
    )

    @sub.command("generate")
    def generate(
        robot: str = typer.Option("paper", help="Robot name (paper) or TOML file."),
        preset: str = typer.Option("small", help="Protocol preset: paper, small or tiny."),
        out: Path = typer.Option(
            Path("data.h5"), "--out", "-o", help="Output HDF5 file (a stem for --split both)."
        ),
        split: str = typer.Option(
            "both", help="train, test, or both (writes OUT_train.h5 and OUT_test.h5)."
        ),
        workers: int = typer.Option(None, min=1, help="Worker processes (default: all cores)."),
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
        from riskplan.datasets import generate_dataset, get_protocol
        from riskplan.errors import InvalidInputError
        from riskplan.robots import load_robot

        if split not in ("train", "test", "both"):
            raise InvalidInputError(f"split: expected train, test or both, got {split!r}")
        protocol = get_protocol(preset)
        rob = load_robot(robot)
        outputs = _outputs(out, split)
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
                        workers=workers,
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

    @sub.command("info")
    def info(
        file: Path = typer.Argument(..., help="Data-set HDF5 file."),
        as_json: bool = typer.Option(False, "--json", help="Print JSON."),
    ) -> None:
        """Summarise a data set: robot, protocol, configurations done/total, point spread."""
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
