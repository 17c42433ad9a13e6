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

from riskplan._validation import check_count
from riskplan.errors import ConvergenceError, DataFormatError, InvalidInputError
from riskplan.kinematics.data import PointCloudData, check_compatible
from riskplan.kinematics.mdn import MDN, MDNModel, Normalisation, mixture_log_prob

log = logging.getLogger(__name__)

CHECKPOINT_NAME = "checkpoint.pt"
CHECKPOINT_FORMAT = "riskplan-mdn-checkpoint"


@dataclass
class TrainConfig:
    """Training options (defaults: a small network that trains in minutes on one core).

    The paper gives the architecture only as Fig. 2 (trunk + three heads); widths,
    learning rate and schedule here are our choices.
    """

    n_components: int = 5
    hidden: tuple[int, ...] = (64, 64)
    head_hidden: tuple[int, ...] = (32,)
    activation: str = "silu"
    epochs: int = 100
    batch_size: int = 32
    points_per_config: int = 256
    lr: float = 3e-3
    weight_decay: float = 0.0
    lr_factor: float = 0.5
    lr_patience: int = 4
    min_lr: float = 1e-5
    early_stop_patience: int = 12
    val_fraction: float = 0.1
    val_points: int = 1024
    seed: int = 0
    dtype: str = "float32"
    max_bad_steps: int = 20

    def validate(self) -> None:
        ints = (
            "n_components",
            "epochs",
            "batch_size",
            "points_per_config",
            "val_points",
            "max_bad_steps",
        )
        for name in ints:
            check_count(getattr(self, name), name, 1)
        for name in ("val_fraction", "lr", "lr_factor", "weight_decay", "min_lr"):
            v = getattr(self, name, 0.0)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float, np.integer, np.floating))
                or not math.isfinite(v)
            ):
                raise InvalidInputError(f"{name}: expected a finite number, got {v!r}")
        for name in ("early_stop_patience", "lr_patience", "seed"):
            check_count(getattr(self, name), name, 0)
        if not 0.0 <= self.val_fraction < 1.0:
            raise InvalidInputError(f"val_fraction: expected in [0, 1), got {self.val_fraction}")
        if not (self.lr > 0 and math.isfinite(self.lr)):
            raise InvalidInputError(f"lr: expected a positive finite number, got {self.lr}")
        if not 0.0 < self.lr_factor < 1.0:
            raise InvalidInputError(f"lr_factor: expected in (0, 1), got {self.lr_factor}")
        if self.dtype not in ("float32", "float64"):
            raise InvalidInputError(f"dtype: expected 'float32' or 'float64', got {self.dtype!r}")

    def to_json(self) -> dict:
        """The options as JSON types (tuples as lists), as stored in ``model.json``.

        Returns
        -------
        dict
            One entry per field.
        """
        d = dataclasses.asdict(self)
        d["hidden"], d["head_hidden"] = list(self.hidden), list(self.head_hidden)
        return d

    @classmethod
    def from_json(cls, obj: dict) -> TrainConfig:
        """Inverse of :meth:`to_json`; unknown keys are ignored, missing ones take their defaults.

        Parameters
        ----------
        obj : dict
            Options by field name.

        Returns
        -------
        TrainConfig
        """
        names = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in obj.items() if k in names}
        for k in ("hidden", "head_hidden"):
            if k in kw:
                kw[k] = tuple(kw[k])
        return cls(**kw)


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


def _batch_loss(net: MDN, x: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Mean NLL (normalised units) of ``points (B, N, 3)`` under ``net(x (B, m))``."""
    log_w, means, u = net(x)
    return -mixture_log_prob(log_w, means, u, points).mean()


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
    config.validate()
    if data.n_configs < 2:
        raise DataFormatError(
            f"data set {data.path!r}: need at least 2 configurations to train (train/validation), got {data.n_configs}"
        )
    dtype = _torch_dtype(config.dtype)
    out = Path(out) if out is not None else None
    if resume and out is None:
        raise InvalidInputError("resume: needs out= (the folder holding checkpoint.pt)")
    if out is not None:
        from riskplan.io import check_output_folder

        check_output_folder(out, "out")
    if out is not None and not resume and not overwrite:
        _refuse_existing_run(out, config)

    train_idx, val_idx = split_indices(data.n_configs, config.val_fraction, config.seed)
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

    history: list[EpochRecord] = []
    start_epoch, best_val, best_epoch, best_state, since_best, total_skipped = (
        0,
        math.inf,
        -1,
        None,
        0,
        0,
    )
    if resume:
        norm, history, start_epoch, best_val, best_epoch, since_best, best_state, total_skipped = (
            _resume(out, data, config, net, opt, sched)
        )

    val = _Evaluator(data, val_idx, norm, config.val_points, config.seed, dtype)
    x_all = (data.displacements - norm.input_mean) / norm.input_scale
    np_dtype = np.float64 if dtype == torch.float64 else np.float32
    centre, scale = norm.output_centre.astype(np_dtype), norm.output_scale.astype(np_dtype)
    n_train, N = train_idx.size, data.n_points
    B = min(config.batch_size, n_train)
    steps = math.ceil(n_train / B)
    stopped_early = since_best >= config.early_stop_patience and best_epoch >= 0
    t_start = time.perf_counter()

    for epoch in range(start_epoch, config.epochs):
        if stopped_early:
            break
        t0 = time.perf_counter()
        net.train()
        rng = np.random.default_rng([config.seed, epoch])
        perm = rng.permutation(train_idx)
        good = (copy.deepcopy(net.state_dict()), copy.deepcopy(opt.state_dict()))
        run_loss, run_n, skipped, consecutive_bad = 0.0, 0, 0, 0
        for step in range(steps):
            idx = perm[step * B : (step + 1) * B]
            pidx = rng.integers(0, N, size=(idx.size, config.points_per_config))
            pts = (data.points[idx[:, None], pidx] - centre) / scale
            x = torch.as_tensor(x_all[idx], dtype=dtype)
            p = torch.as_tensor(pts, dtype=dtype)
            opt.zero_grad(set_to_none=True)
            loss = _batch_loss(net, x, p)
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
                skipped += 1
                consecutive_bad += 1
                log.warning(
                    "epoch %d step %d: non-finite loss or gradient; step skipped", epoch, step
                )
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
                on_step(step, steps, lv + norm.log_scale_sum)
        net.eval()
        train_nll = run_loss / max(run_n, 1) + norm.log_scale_sum if run_n else math.nan
        val_nll = val(net) if not val.empty else train_nll
        total_skipped += skipped
        if math.isfinite(val_nll):
            sched.step(val_nll)
        improved = math.isfinite(val_nll) and val_nll < best_val
        if improved:
            best_val, best_epoch, since_best = val_nll, epoch, 0
            best_state = copy.deepcopy(net.state_dict())
        else:
            since_best += 1
        rec = EpochRecord(
            epoch,
            train_nll,
            val_nll,
            float(opt.param_groups[0]["lr"]),
            skipped,
            time.perf_counter() - t0,
        )
        history.append(rec)
        stopped_early = since_best >= config.early_stop_patience
        if out is not None:
            if improved:
                _save_best(net, norm, data, config, history, out, model_io)
            counters = (epoch, best_val, best_epoch, since_best, best_state, total_skipped)
            save_checkpoint(
                out / CHECKPOINT_NAME,
                _checkpoint(net, opt, sched, norm, config, data, history, counters),
            )
        if on_epoch is not None:
            on_epoch(rec)
        if max_seconds is not None and time.perf_counter() - t_start > max_seconds:
            log.info("time budget of %.0f s spent after epoch %d", max_seconds, epoch)
            break

    if best_state is None:
        if not history:
            raise ConvergenceError(
                "training produced no epoch (epochs already reached by the checkpoint?)",
                iterations=start_epoch,
            )
        raise ConvergenceError(
            "training produced no finite validation loss", iterations=len(history)
        )
    net.load_state_dict(best_state)
    net.eval()
    model = _model_with_history(net, norm, data, config, history, best_epoch, finished=True)
    if out is not None:
        model_io.save_model(model, out)
    return TrainResult(model, history, best_epoch, best_val, stopped_early, total_skipped)


def _resume(out, data, config, net, opt, sched):
    """Load ``out``'s checkpoint into ``net``, ``opt`` and ``sched``; the loop's counters."""
    ck = load_checkpoint(out / CHECKPOINT_NAME)
    _check_resume(ck, data, config)
    net.load_state_dict(ck["net"])
    opt.load_state_dict(ck["optimizer"])
    sched.load_state_dict(ck["scheduler"])
    norm = Normalisation.from_json(ck["normalisation"])
    history = [EpochRecord(**h) for h in ck["history"]]
    start_epoch = ck["epoch"] + 1
    best_val, best_epoch, since_best = ck["best_val"], ck["best_epoch"], ck["since_best"]
    log.info("resuming at epoch %d (best NLL %.4f at epoch %d)", start_epoch, best_val, best_epoch)
    rest = (ck["best_state"], ck["skipped_steps"])
    return (norm, history, start_epoch, best_val, best_epoch, since_best, *rest)


def _checkpoint(net, opt, sched, norm, config, data, history, counters):
    """The checkpoint written after each epoch (what ``_resume`` reads back)."""
    epoch, best_val, best_epoch, since_best, best_state, total_skipped = counters
    return {
        "format": CHECKPOINT_FORMAT,
        "format_version": 1,
        "net": net.state_dict(),
        "optimizer": opt.state_dict(),
        "scheduler": sched.state_dict(),
        "normalisation": norm.to_json(),
        "config": config.to_json(),
        "history": [dataclasses.asdict(h) for h in history],
        "epoch": epoch,
        "best_val": best_val,
        "best_epoch": best_epoch,
        "since_best": since_best,
        "best_state": best_state,
        "skipped_steps": total_skipped,
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
