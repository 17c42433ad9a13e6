"""`riskplan` subcommands for the kinematics area: train, predict, sweep, evaluate.

Heavy imports (torch, h5py, matplotlib) stay inside the commands.

``train`` and ``sweep`` declare the same training options (``_BATCH_SIZE`` ... ``_SEED``,
shared objects, so one default and one help text each) and build their ``TrainConfig`` with
one helper, :func:`_config`. Their signatures still list those options one by one on
purpose: typer reads a command's options from its signature and has no option groups.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

# Options that `train` and `sweep` share (same names as the TrainConfig fields they set).
_BATCH_SIZE = typer.Option(32, help="Configurations per step.")
_POINTS_PER_CONFIG = typer.Option(256, help="Points drawn per configuration per step.")
_LR = typer.Option(3e-3, help="Adam learning rate.")
_HIDDEN = typer.Option("64,64", help="Comma-separated widths of the shared trunk.")
_HEAD_HIDDEN = typer.Option(
    "32", help="Comma-separated hidden widths of each head ('' for linear heads)."
)
_ACTIVATION = typer.Option("silu", help="silu, tanh or relu.")
_SEED = typer.Option(0, min=0, help="Seed (initialisation, split, batches).")


def _config(options: dict, **renamed):
    """The validated ``TrainConfig`` of a command: every option named like a ``TrainConfig``
    field (pass the command's ``locals()``), plus ``renamed`` fields; ``hidden`` and
    ``head_hidden`` are comma-separated widths (:func:`riskplan.parsing.parse_numbers`)."""
    import dataclasses

    from riskplan.kinematics.training import TrainConfig
    from riskplan.parsing import parse_numbers

    names = {f.name for f in dataclasses.fields(TrainConfig)}
    kw = {k: v for k, v in options.items() if k in names}
    kw.update(renamed)
    for key in ("hidden", "head_hidden"):
        opt = "--" + key.replace("_", "-")
        kw[key] = tuple(parse_numbers(kw[key], opt, integers=True, allow_empty=True))
    cfg = TrainConfig(**kw)
    cfg.validate()
    return cfg


def _parse_displacements(spec: str):
    """``--displacements``: ``"0.01,0,0,0"`` (one configuration, ``(m,)``), rows separated
    by ``;`` (``(N, m)``), or a table file (:func:`riskplan.parsing.read_table`)."""
    from riskplan.parsing import TABLE_SUFFIXES, parse_rows, read_table

    if Path(spec).suffix.lower() in TABLE_SUFFIXES:
        return read_table(spec, "--displacements")
    arr = parse_rows(spec, "--displacements")
    return arr[0] if arr.shape[0] == 1 else arr


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app: the group ``riskplan model ...`` and
    the old ungrouped spellings (``riskplan model train`` ...) as hidden aliases."""
    from riskplan.commands._shared import add_group

    model_app = add_group(
        app, "model", "The mixture density network: train, predict, sweep, evaluate."
    )
    train = _add_train(model_app)
    predict = _add_predict(model_app)
    sweep = _add_sweep(model_app)
    evaluate = _add_evaluate(model_app)
    for command in (train, predict, sweep, evaluate):  # the spellings before the group
        app.command(command.__name__, hidden=True)(command)


def _add_train(model_app: typer.Typer):
    """Add ``train`` to ``model_app``; returns the command function."""

    @model_app.command()
    def train(
        data: Path = typer.Option(
            ..., "--data", help="Training data set (HDF5 from `riskplan dataset`)."
        ),
        out: Path = typer.Option(
            ..., "--out", "-o", help="Model folder (weights.pt, model.json, checkpoint.pt)."
        ),
        components: int = typer.Option(5, "--components", "-k", help="Mixture components K."),
        epochs: int = typer.Option(100, min=1, help="Maximum epochs."),
        batch_size: int = _BATCH_SIZE,
        points_per_config: int = _POINTS_PER_CONFIG,
        lr: float = _LR,
        hidden: str = _HIDDEN,
        head_hidden: str = _HEAD_HIDDEN,
        activation: str = _ACTIVATION,
        val_fraction: float = typer.Option(
            0.1, help="Fraction of configurations held out for validation."
        ),
        patience: int = typer.Option(
            12, min=0, help="Early stopping: epochs without validation improvement."
        ),
        lr_patience: int = typer.Option(
            4, min=0, help="Halve the learning rate after this many epochs without improvement."
        ),
        seed: int = _SEED,
        dtype: str = typer.Option("float32", help="float32 or float64."),
        resume: bool = typer.Option(False, "--resume", help="Continue from OUT/checkpoint.pt."),
        overwrite: bool = typer.Option(
            False, "--overwrite", help="Start afresh even if OUT holds a checkpoint or a model."
        ),
    ) -> None:
        """Train a mixture density network on a point-cloud data set."""
        cfg = _config(locals(), n_components=components, early_stop_patience=patience)

        from riskplan.commands._shared import output_folder, progress_bar, stop_interrupted
        from riskplan.kinematics.data import read_point_clouds
        from riskplan.kinematics.training import train as run_train

        ds = read_point_clouds(data)
        with output_folder(out), progress_bar() as bar:
            task = bar.add_task("training", total=cfg.epochs, status="")
            state = {"best": float("inf")}

            def on_step(step, steps, loss):
                bar.update(task, status=f"step {step + 1}/{steps} {loss:.3f}")

            def on_epoch(rec):
                state["best"] = min(state["best"], rec.val_nll)
                bar.update(
                    task,
                    completed=rec.epoch + 1,
                    status=f"val {rec.val_nll:.3f} best {state['best']:.3f}",
                )

            try:
                res = run_train(
                    ds,
                    cfg,
                    out=out,
                    resume=resume,
                    overwrite=overwrite,
                    on_epoch=on_epoch,
                    on_step=on_step,
                )
            except KeyboardInterrupt:
                raise stop_interrupted(
                    bar,
                    f"the checkpoint in {out} is kept; continue with the same command plus --resume",
                ) from None
        # without a validation split (--val-fraction 0, or too few configurations) training
        # scores and early-stops on the training NLL
        from riskplan.kinematics.training import split_indices

        has_val = split_indices(ds.n_configs, cfg.val_fraction, cfg.seed)[1].size > 0
        scored = "validation" if has_val else "training (no validation split)"
        typer.echo(
            f"best {scored} NLL {res.best_val_nll:.4f} nats/point at epoch {res.best_epoch} "
            f"({len(res.history)} epochs{', stopped early' if res.stopped_early else ''}, {res.skipped_steps} skipped steps); model: {out}"
        )

    return train


def _add_predict(model_app: typer.Typer):
    """Add ``predict`` to ``model_app``; returns the command function."""

    @model_app.command()
    def predict(
        model: Path = typer.Option(
            ..., "--model", "-m", help="Model folder, or a shipped model name ('paper')."
        ),
        displacements: str = typer.Option(
            None,
            "--displacements",
            "-d",
            help="'d1,d2,...' (m); ';' between configurations; or a .csv/.txt/.json/.npy file.",
        ),
        tensions: str = typer.Option(
            None,
            "--tensions",
            "-t",
            help="Or tendon tensions 't1,t2,...' (N; ';' between configurations), converted "
            "to displacements through the model's robot.",
        ),
        json_out: bool = typer.Option(False, "--json", help="Print the mixture as JSON."),
    ) -> None:
        """Predict the Gaussian mixture of the robot's geometry for tendon displacements (or tensions)."""
        from riskplan.errors import InvalidInputError
        from riskplan.kinematics import load_model

        if (displacements is None) == (tensions is None):
            raise InvalidInputError("give exactly one of --displacements and --tensions")
        m = load_model(model)
        if m.metadata.get("finished") is False:
            typer.secho(
                f"warning: {model} is an unfinished model (its training run has not ended); resume it with riskplan model train --resume",
                fg="yellow",
                err=True,
            )
        if tensions is not None:
            from riskplan.commands._shared import rows_from_tensions

            d = rows_from_tensions(m.robot, tensions)
            d = d[0] if d.shape[0] == 1 else d
        else:
            d = _parse_displacements(displacements)
        gm = m.predict(d)
        obj = {
            "displacements": d.tolist(),
            "n_components": m.n_components,
            "weights": gm.weights.numpy().tolist(),
            "means": gm.means.numpy().tolist(),
            "covariances": gm.covariances.numpy().tolist(),
            "precision_cholesky": gm.precision_cholesky.numpy().tolist(),
            "units": "metres, robot base frame",
        }
        if json_out:
            typer.echo(json.dumps(obj))
            return
        import numpy as np

        w = np.atleast_2d(gm.weights.numpy())
        mu = gm.means.numpy().reshape(-1, m.n_components, 3)
        for c in range(w.shape[0]):
            typer.echo(f"configuration {c}:")
            for k in range(m.n_components):
                typer.echo(
                    f"  w={w[c, k]:.3f}  mean=({', '.join(f'{v * 1e3:8.2f}' for v in mu[c, k])}) mm"
                )

    return predict


def _add_sweep(model_app: typer.Typer):
    """Add ``sweep`` to ``model_app``; returns the command function."""

    @model_app.command()
    def sweep(
        data: Path = typer.Option(..., "--data", help="Training data set."),
        test: Path = typer.Option(..., "--test", help="Test data set."),
        out: Path = typer.Option(
            ..., "--out", "-o", help="Output folder (K*/ models, sweep.json, fig4_nll_vs_k.png)."
        ),
        components: str = typer.Option("1-10", help="K values, e.g. '1-10' or '1,3,5'."),
        epochs: int = typer.Option(40, min=1, help="Maximum epochs per K."),
        batch_size: int = _BATCH_SIZE,
        points_per_config: int = _POINTS_PER_CONFIG,
        lr: float = _LR,
        hidden: str = _HIDDEN,
        head_hidden: str = _HEAD_HIDDEN,
        activation: str = _ACTIVATION,
        patience: int = typer.Option(8, min=0, help="Early stopping patience (epochs)."),
        seed: int = _SEED,
        workers: int = typer.Option(1, min=1, help="Train this many K at once (processes)."),
        collapse_threshold: float = typer.Option(
            0.01, help="Mode collapse: weight below this on 99% of test configurations."
        ),
        nll_tolerance: float = typer.Option(
            0.05, help="Recommended K: smallest K within this many nats/point of the best."
        ),
    ) -> None:
        """Train one model per K and plot test NLL vs K (the paper's Fig. 4)."""
        cfg = _config(locals(), early_stop_patience=patience)
        from riskplan.commands._shared import output_folder, progress_bar
        from riskplan.io import check_output_folder, write_json_atomic
        from riskplan.kinematics.plotting import fig_nll_vs_components
        from riskplan.kinematics.sweep import parse_components
        from riskplan.kinematics.sweep import sweep as run_sweep

        ks = parse_components(components)
        check_output_folder(out, "--out")
        with output_folder(out), progress_bar() as bar:
            task = bar.add_task("K sweep", total=len(ks), status="")

            def on_result(i, r):
                bar.update(
                    task, advance=1, status=f"K={r['n_components']} test NLL {r['test_nll']:.3f}"
                )

            res = run_sweep(
                data,
                test,
                ks,
                cfg,
                out=out,
                workers=workers,
                collapse_threshold=collapse_threshold,
                nll_tolerance=nll_tolerance,
                on_result=on_result,
            )
            write_json_atomic(out / "sweep.json", res.to_json())
            import matplotlib.pyplot as plt

            fig = fig_nll_vs_components(res)
            fig.savefig(out / "fig4_nll_vs_k.png", dpi=120, bbox_inches="tight")
            plt.close(fig)
        for e in res.entries:
            flag = f"  collapsed components {e.collapsed}" if e.collapsed else ""
            flag += f"  FAILED: {e.error}" if e.error else ""
            typer.echo(f"K={e.n_components:2d}  test NLL {e.test_nll:9.4f}{flag}")
        typer.echo(f"recommended K = {res.recommended} ({res.rule}); results in {out}")

    return sweep


def _add_evaluate(model_app: typer.Typer):
    """Add ``evaluate`` to ``model_app``; returns the command function."""

    @model_app.command()
    def evaluate(
        model: Path = typer.Option(
            ..., "--model", "-m", help="Model folder, or a shipped model name ('paper')."
        ),
        data: Path = typer.Option(..., "--data", help="Test data set."),
        out: Path = typer.Option(
            ..., "--out", "-o", help="Output folder (evaluation.json, Fig. 5 PNG + HTML)."
        ),
        samples: int = typer.Option(
            4096, min=1, help="Mixture samples per configuration for the HDR thresholds."
        ),
        chamfer_points: int = typer.Option(
            2048, min=1, help="Points per cloud for the Chamfer distance."
        ),
        max_configs: int = typer.Option(
            0, min=0, help="Evaluate a random subset of this many configurations (0: all)."
        ),
        figure_configs: int = typer.Option(
            2, min=1, help="Random test configurations shown in Fig. 5."
        ),
        seed: int = typer.Option(0, min=0),
    ) -> None:
        """Test NLL, Chamfer distance, HDR calibration and the paper's Fig. 5."""

        from riskplan.commands._shared import output_folder
        from riskplan.io import check_output_folder, write_json_atomic
        from riskplan.kinematics import load_model
        from riskplan.kinematics.data import read_point_clouds
        from riskplan.kinematics.evaluation import evaluate as run_eval
        from riskplan.kinematics.plotting import fig_samples_vs_truth, plotly_samples_vs_truth

        check_output_folder(out, "--out")
        m = load_model(model)
        ds = read_point_clouds(data)
        with output_folder(out):
            ev = run_eval(
                m,
                ds,
                n_samples=samples,
                chamfer_points=chamfer_points,
                seed=seed,
                max_configs=max_configs or None,
            )
            obj = {
                **ev.to_json(),
                "model": str(model),
                "data": str(data),
                "n_components": m.n_components,
            }
            write_json_atomic(out / "evaluation.json", obj)
            import matplotlib.pyplot as plt

            fig = fig_samples_vs_truth(m, ds, n_configs=figure_configs, seed=seed)
            fig.savefig(out / "fig5_samples_vs_truth.png", dpi=110, bbox_inches="tight")
            plt.close(fig)
            plotly_samples_vs_truth(m, ds, n_configs=figure_configs, seed=seed).write_html(
                out / "fig5_samples_vs_truth.html", include_plotlyjs=True
            )
        typer.echo(f"test NLL {ev.nll:.4f} nats/point; Chamfer {ev.chamfer * 1e3:.3f} mm")
        typer.echo(
            "HDR calibration: " + ", ".join(f"{a:g} -> {c:.3f}" for a, c in ev.calibration.items())
        )
        typer.echo(f"results in {out}")

    return evaluate
