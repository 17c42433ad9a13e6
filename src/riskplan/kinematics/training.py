"""Training the MDN on point-cloud data sets (MDN paper, section III, Fig. 1).

Adam on mini-batches of configurations; each step draws ``points_per_config`` points
(uniformly, with replacement) from every configuration's concatenated clouds and
minimises their mean negative log-likelihood (the paper's loss, after eq. 7). A
validation split (by configuration) drives a reduce-on-plateau learning-rate schedule
and early stopping; the best validation model is returned.

Reproducibility: the shuffle and point draws of epoch ``e`` come from
``numpy.random.default_rng([seed, e])``, so a run resumed from the checkpoint of
epoch ``e`` continues exactly as the uninterrupted run would have.

Robustness: a step whose loss or gradient is not finite is skipped (the parameters
and Adam moments are left as they were); if parameters ever become non-finite after a
step, model and optimiser roll back to the state at the start of the epoch. After
``max_bad_steps`` consecutive bad steps training stops with :class:`ConvergenceError`.
"""

from __future__ import annotations

import copy
import dataclasses
import io
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from riskplan.errors import ConvergenceError, DataFormatError, InvalidInputError
from riskplan.kinematics.data import PointCloudData, check_compatible
from riskplan.kinematics.mdn import MDN, MDNModel, Normalisation, mdn_nll, mixture_log_prob
from riskplan.kinematics.train_config import TrainConfig

log = logging.getLogger(__name__)

CHECKPOINT_NAME = "checkpoint.pt"
CHECKPOINT_FORMAT = "riskplan-mdn-checkpoint"


@dataclass
class EpochRecord:
    """One epoch of :func:`train`: NLLs in nats per point (positions in metres), the learning
    rate, the optimiser steps skipped for a non-finite loss or gradient, and the epoch's wall time (s)."""

    epoch: int
    train_nll: float
    val_nll: float
    lr: float
    skipped_steps: int
    seconds: float


@dataclass
class TrainResult:
    """The best model (lowest validation NLL) and the training history (NLL in nats per point, metres)."""

    model: MDNModel
    history: list[EpochRecord] = field(default_factory=list)
    best_epoch: int = -1
    best_val_nll: float = math.inf
    stopped_early: bool = False
    skipped_steps: int = 0


def _torch_dtype(name: str) -> torch.dtype:
    return torch.float64 if name == "float64" else torch.float32


def split_indices(n: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random split of ``n`` configurations into (train, validation) index arrays."""
    n_val = round(val_fraction * n)
    if val_fraction > 0 and n >= 2:
        n_val = min(max(n_val, 1), n - 1)
    perm = np.random.default_rng([seed, 7919]).permutation(n)
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def _params_finite(net: torch.nn.Module) -> bool:
    return all(bool(torch.isfinite(p).all()) for p in net.parameters())


def _grads_finite(net: torch.nn.Module) -> bool:
    return all(p.grad is None or bool(torch.isfinite(p.grad).all()) for p in net.parameters())


def build_model(
    net: MDN,
    norm: Normalisation,
    data: PointCloudData,
    config: TrainConfig,
    extra: dict | None = None,
) -> MDNModel:
    meta = {
        "training": config.to_json(),
        "data": {
            "path": data.path,
            "content_hash": data.content_hash,
            "n_configs": data.n_configs,
            "n_points": data.n_points,
        },
    }
    if extra:
        meta.update(extra)
    return MDNModel(
        copy.deepcopy(net).eval(), norm, data.limits.copy(), data.robot_toml, data.robot_name, meta
    )


class _Evaluator:
    """Validation NLL on a fixed subsample of points (the same every epoch)."""

    def __init__(
        self,
        data: PointCloudData,
        idx: np.ndarray,
        norm: Normalisation,
        n_points: int,
        seed: int,
        dtype,
    ):
        self.empty = idx.size == 0
        if self.empty:
            return
        rng = np.random.default_rng([seed, 104729])
        N = data.n_points
        take = min(n_points, N)
        pidx = (
            np.stack([rng.choice(N, size=take, replace=False) for _ in idx])
            if take < N
            else np.broadcast_to(np.arange(N), (idx.size, N))
        )
        pts = data.points[idx[:, None], pidx]
        self.x = torch.as_tensor(
            (data.displacements[idx] - norm.input_mean) / norm.input_scale, dtype=dtype
        )
        self.p = torch.as_tensor((pts - norm.output_centre) / norm.output_scale, dtype=dtype)
        self.offset = norm.log_scale_sum

    def __call__(self, net: MDN) -> float:
        if self.empty:
            return math.nan
        total = 0.0
        with torch.no_grad():
            for s in range(0, self.x.shape[0], 256):
                lp = mixture_log_prob(*net(self.x[s : s + 256]), self.p[s : s + 256])
                total += float(-lp.sum(-1).sum())
        return total / (self.p.shape[0] * self.p.shape[1]) + self.offset


def train(
    data: PointCloudData,
    config: TrainConfig | None = None,
    *,
    out=None,
    resume: bool = False,
    overwrite: bool = False,
    on_epoch: Callable[[EpochRecord], None] | None = None,
    on_step: Callable[[int, int, float], None] | None = None,
    max_seconds: float | None = None,
) -> TrainResult:
    """Fit an MDN to ``data`` by minimising the negative log-likelihood (the loss after eq. 7).

    Each step draws ``points_per_config`` points of each configuration in a batch and minimises
    the mean of ``-log p(x | u)`` (eq. 1 with eqs. 4-6) with Adam; the learning rate falls by
    ``lr_factor`` when the validation NLL stalls, and training stops early after
    ``early_stop_patience`` epochs without improvement. Models saved during training carry
    ``"finished": false`` in their metadata, the final one ``"finished": true``;
    :func:`~riskplan.kinematics.load_model` warns about unfinished ones.

    Raises :class:`DataFormatError` for unusable data or a mismatched checkpoint, before
    any training, and :class:`ConvergenceError` if training keeps producing non-finite losses.

    Parameters
    ----------
    data : PointCloudData
        Displacements ``(N, m)`` and point clouds ``(N, P, 3)`` (m) of one robot.
    config : TrainConfig, optional
        Architecture and optimiser options (default ``TrainConfig()``).
    out : str or path, optional
        Folder for ``checkpoint.pt`` (written atomically after every epoch) and the best model
        (``weights.pt`` + ``model.json``, see :mod:`riskplan.kinematics.model_io`).
    resume : bool
        Continue from ``out/checkpoint.pt`` (the data set must be the same, by content hash).
    overwrite : bool
        Allow a folder that already holds a checkpoint or a model (refused otherwise, so a rerun
        does not silently discard an interrupted run).
    on_epoch : callable, optional
        ``on_epoch(record)`` after each epoch, with an :class:`EpochRecord`.
    on_step : callable, optional
        ``on_step(step, steps_per_epoch, loss)`` after each optimiser step.
    max_seconds : float, optional
        Stop after the first epoch that ends past this wall-clock budget (the result is still
        the best model so far).

    Returns
    -------
    TrainResult
        The best-validation model and the history; reported NLLs are nats per point with
        positions in metres.
    """
    from riskplan.kinematics import model_io

    config = config or TrainConfig()
    out = _check_run(data, config, out, resume, overwrite)
    dtype = _torch_dtype(config.dtype)
    train_idx, val_idx = split_indices(data.n_configs, config.val_fraction, config.seed)
    net, opt, sched, norm = _initial_state(data, config, train_idx, dtype)
    progress = _resume(out, data, config, net, opt, sched) if resume else _Progress(norm)
    norm = progress.norm
    val = _Evaluator(data, val_idx, norm, config.val_points, config.seed, dtype)
    batches = _Batches(data, train_idx, norm, config.batch_size, dtype)
    stopped_early = progress.since_best >= config.early_stop_patience and progress.best_epoch >= 0
    t_start = time.perf_counter()

    for epoch in range(progress.start_epoch, config.epochs):
        if stopped_early:
            break
        t0 = time.perf_counter()
        train_nll, skipped = _train_epoch(net, opt, batches, epoch, config, norm, on_step)
        val_nll = val(net) if not val.empty else train_nll
        improved = progress.record(net, sched, epoch, val_nll)
        rec = EpochRecord(
            epoch,
            train_nll,
            val_nll,
            float(opt.param_groups[0]["lr"]),
            skipped,
            time.perf_counter() - t0,
        )
        progress.total_skipped += skipped
        progress.history.append(rec)
        stopped_early = progress.since_best >= config.early_stop_patience
        if out is not None:
            if improved:
                _save_best(net, norm, data, config, progress.history, out, model_io)
            state = _checkpoint(net, opt, sched, config, data, progress, epoch)
            save_checkpoint(out / CHECKPOINT_NAME, state)
        if on_epoch is not None:
            on_epoch(rec)
        if max_seconds is not None and time.perf_counter() - t_start > max_seconds:
            log.info("time budget of %.0f s spent after epoch %d", max_seconds, epoch)
            break

    model = _best_model(net, data, config, progress)
    if out is not None:
        model_io.save_model(model, out)
    p = progress
    return TrainResult(model, p.history, p.best_epoch, p.best_val, stopped_early, p.total_skipped)


@dataclass
class _Progress:
    """What the epoch loop carries from epoch to epoch (and a checkpoint stores with the
    network, optimiser and schedule): the normalisation, the history, the best validation
    NLL so far with its epoch and weights, and the skip counters."""

    norm: Normalisation
    history: list[EpochRecord] = field(default_factory=list)
    start_epoch: int = 0
    best_val: float = math.inf
    best_epoch: int = -1
    best_state: dict | None = None
    since_best: int = 0
    total_skipped: int = 0

    def record(self, net: MDN, sched, epoch: int, val_nll: float) -> bool:
        """Step the plateau schedule on the epoch's validation NLL and keep the weights if
        they are the best so far; whether they are."""
        if math.isfinite(val_nll):
            sched.step(val_nll)
        improved = math.isfinite(val_nll) and val_nll < self.best_val
        if improved:
            self.best_val, self.best_epoch, self.since_best = val_nll, epoch, 0
            self.best_state = copy.deepcopy(net.state_dict())
        else:
            self.since_best += 1
        return improved


def _check_run(data, config, out, resume, overwrite) -> Path | None:
    """Validate ``train``'s arguments before any work; ``out`` as a path."""
    config.validate()
    if data.n_configs < 2:
        raise DataFormatError(
            f"data set {data.path!r}: need at least 2 configurations to train (train/validation), got {data.n_configs}"
        )
    out = Path(out) if out is not None else None
    if resume and out is None:
        raise InvalidInputError("resume: needs out= (the folder holding checkpoint.pt)")
    if out is not None:
        from riskplan.io import check_output_folder

        check_output_folder(out, "out")
    if out is not None and not resume and not overwrite:
        _refuse_existing_run(out, config)
    return out


def _initial_state(data, config, train_idx, dtype):
    """The seeded network, Adam, the plateau schedule and the normalisation fitted on the
    training configurations."""
    from riskplan.kinematics.data import angle_columns

    angles = angle_columns(data.robot_toml)  # a base rotation enters as (cos, sin)
    norm = Normalisation.fit(data.displacements[train_idx], data.points[train_idx], angles)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        net = MDN(
            data.n_tendons,
            config.n_components,
            3,
            config.hidden,
            config.head_hidden,
            config.activation,
            angles,
        ).to(dtype)
    opt = torch.optim.Adam(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(
        opt, mode="min", factor=config.lr_factor, patience=config.lr_patience, min_lr=config.min_lr
    )
    return net, opt, sched, norm


class _Batches:
    """Normalised mini-batches of the training configurations: inputs ``(B, m)`` and
    ``points_per_config`` points ``(B, P, 3)`` drawn with replacement from each cloud."""

    def __init__(self, data, train_idx, norm, batch_size, dtype):
        self.data, self.train_idx, self.dtype = data, train_idx, dtype
        self.x_all = (data.displacements - norm.input_mean) / norm.input_scale
        np_dtype = np.float64 if dtype == torch.float64 else np.float32
        self.centre = norm.output_centre.astype(np_dtype)
        self.scale = norm.output_scale.astype(np_dtype)
        self.size = min(batch_size, train_idx.size)
        self.steps = math.ceil(train_idx.size / self.size)

    def draw(self, idx: np.ndarray, n_points: int, rng) -> tuple[torch.Tensor, torch.Tensor]:
        pidx = rng.integers(0, self.data.n_points, size=(idx.size, n_points))
        pts = (self.data.points[idx[:, None], pidx] - self.centre) / self.scale
        x = torch.as_tensor(self.x_all[idx], dtype=self.dtype)
        return x, torch.as_tensor(pts, dtype=self.dtype)


def _train_epoch(net, opt, batches, epoch, config, norm, on_step) -> tuple[float, int]:
    """One pass over the training configurations in the order and with the points drawn by
    ``default_rng([seed, epoch])``; (mean training NLL in nats per point, steps skipped)."""
    net.train()
    rng = np.random.default_rng([config.seed, epoch])
    perm = rng.permutation(batches.train_idx)
    good = (copy.deepcopy(net.state_dict()), copy.deepcopy(opt.state_dict()))
    run_loss, run_n, skipped, consecutive_bad = 0.0, 0, 0, 0
    B = batches.size
    for step in range(batches.steps):
        idx = perm[step * B : (step + 1) * B]
        x, p = batches.draw(idx, config.points_per_config, rng)
        opt.zero_grad(set_to_none=True)
        loss = mdn_nll(net, x, p)
        if not _optimiser_step(net, opt, loss, good):
            skipped += 1
            consecutive_bad += 1
            log.warning("epoch %d step %d: non-finite loss or gradient; step skipped", epoch, step)
            if consecutive_bad >= config.max_bad_steps:
                raise ConvergenceError(
                    f"training diverged: {consecutive_bad} consecutive steps with non-finite loss or gradient at epoch {epoch}",
                    residual=float(loss.detach()) if loss.numel() == 1 else None,
                    iterations=epoch,
                )
            continue
        consecutive_bad = 0
        lv = float(loss.detach())
        run_loss += lv * idx.size
        run_n += idx.size
        if on_step is not None:
            on_step(step, batches.steps, lv + norm.log_scale_sum)
    net.eval()
    train_nll = run_loss / max(run_n, 1) + norm.log_scale_sum if run_n else math.nan
    return train_nll, skipped


def _optimiser_step(net, opt, loss, good) -> bool:
    """An Adam step on ``loss`` when it and its gradient are finite; parameters that turn
    non-finite anyway roll back to ``good`` (the epoch's start). Whether the step counted."""
    ok = bool(torch.isfinite(loss))
    if ok:
        loss.backward()
        ok = _grads_finite(net)
    if ok:
        opt.step()
        if not _params_finite(net):  # should not happen after finite gradients; roll back
            net.load_state_dict(good[0])
            opt.load_state_dict(good[1])
            ok = False
    if not ok:
        opt.zero_grad(set_to_none=True)
    return ok


def _best_model(net, data, config, progress) -> MDNModel:
    """The network with the best validation weights, as the finished model."""
    if progress.best_state is None:
        if not progress.history:
            raise ConvergenceError(
                "training produced no epoch (epochs already reached by the checkpoint?)",
                iterations=progress.start_epoch,
            )
        raise ConvergenceError(
            "training produced no finite validation loss", iterations=len(progress.history)
        )
    net.load_state_dict(progress.best_state)
    net.eval()
    h, best = progress.history, progress.best_epoch
    return _model_with_history(net, progress.norm, data, config, h, best, finished=True)


def _resume(out, data, config, net, opt, sched) -> _Progress:
    """Load ``out``'s checkpoint into ``net``, ``opt`` and ``sched``; the loop's progress."""
    ck = load_checkpoint(out / CHECKPOINT_NAME)
    _check_resume(ck, data, config)
    net.load_state_dict(ck["net"])
    opt.load_state_dict(ck["optimizer"])
    sched.load_state_dict(ck["scheduler"])
    progress = _Progress(
        Normalisation.from_json(ck["normalisation"]),
        [EpochRecord(**h) for h in ck["history"]],
        ck["epoch"] + 1,
        ck["best_val"],
        ck["best_epoch"],
        ck["best_state"],
        ck["since_best"],
        ck["skipped_steps"],
    )
    p = progress
    log.info(
        "resuming at epoch %d (best NLL %.4f at epoch %d)", p.start_epoch, p.best_val, p.best_epoch
    )
    return progress


def _checkpoint(net, opt, sched, config, data, progress: _Progress, epoch: int) -> dict:
    """The checkpoint written after each epoch (what ``_resume`` reads back)."""
    p = progress
    return {
        "format": CHECKPOINT_FORMAT,
        "format_version": 1,
        "net": net.state_dict(),
        "optimizer": opt.state_dict(),
        "scheduler": sched.state_dict(),
        "normalisation": p.norm.to_json(),
        "config": config.to_json(),
        "history": [dataclasses.asdict(h) for h in p.history],
        "epoch": epoch,
        "best_val": p.best_val,
        "best_epoch": p.best_epoch,
        "since_best": p.since_best,
        "best_state": p.best_state,
        "skipped_steps": p.total_skipped,
        "data_hash": data.content_hash,
        "robot_toml": data.robot_toml,
        "n_tendons": data.n_tendons,
    }


def _model_with_history(net, norm, data, config, history, best_epoch, *, finished: bool):
    """:func:`build_model` with the training record (epoch history, best epoch, finished)."""
    record = {
        "history": [dataclasses.asdict(h) for h in history],
        "best_epoch": best_epoch,
        "finished": finished,
    }
    return build_model(net, norm, data, config, record)


def _save_best(net, norm, data, config, history, out, model_io) -> None:
    model = _model_with_history(net, norm, data, config, history, history[-1].epoch, finished=False)
    model_io.save_model(model, out)


def _refuse_existing_run(out: Path, config: TrainConfig) -> None:
    """Raise :class:`InvalidInputError` if ``out`` holds a checkpoint or a model (see :func:`train`)."""
    from riskplan.kinematics.model_io import META_NAME

    ck_path = out / CHECKPOINT_NAME
    if ck_path.exists():
        try:
            ck = load_checkpoint(ck_path)
            state = f"a checkpoint at epoch {int(ck['epoch']) + 1} of {TrainConfig.from_json(ck['config']).epochs}"
        except (DataFormatError, KeyError, TypeError, ValueError):
            state = "an unreadable checkpoint"
        raise InvalidInputError(
            f"out: {str(out)!r} holds {state}; pass resume=True (--resume) to continue it or "
            "overwrite=True (--overwrite) to start afresh"
        )
    if (out / META_NAME).exists():
        raise InvalidInputError(
            f"out: {str(out)!r} already holds a model; pass overwrite=True (--overwrite) to replace it"
        )


def _check_resume(ck: dict, data: PointCloudData, config: TrainConfig) -> None:
    check_compatible(
        {"robot_toml": ck["robot_toml"], "n_tendons": ck["n_tendons"]}, data, what="data set"
    )
    if ck["data_hash"] != data.content_hash:
        raise DataFormatError(
            f"checkpoint was trained on a data set with content hash {ck['data_hash'][:12]}..., "
            f"but {data.path!r} has {data.content_hash[:12]}...; resume with the same data"
        )
    saved = TrainConfig.from_json(ck["config"])
    for name in (
        "n_components",
        "hidden",
        "head_hidden",
        "activation",
        "dtype",
        "seed",
        "val_fraction",
    ):
        if getattr(saved, name) != getattr(config, name):
            raise DataFormatError(
                f"checkpoint has {name}={getattr(saved, name)!r} but the run asks for {getattr(config, name)!r}"
            )


def save_checkpoint(path, state: dict) -> None:
    from riskplan.io import atomic_path

    buf = io.BytesIO()
    torch.save(state, buf)
    with atomic_path(path, suffix=".pt") as tmp:
        tmp.write_bytes(buf.getvalue())


def load_checkpoint(path) -> dict:
    """Read a training checkpoint; :class:`DataFormatError` if missing or corrupted."""
    from riskplan.io import read_file_with

    path = Path(path)
    ck = read_file_with(
        path,
        lambda p: torch.load(p, map_location="cpu", weights_only=True),
        "checkpoint",
        error=DataFormatError,
        hint=" (nothing to resume)",
    )
    if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
        raise DataFormatError(f"checkpoint {str(path)!r}: not a riskplan MDN checkpoint")
    return ck
