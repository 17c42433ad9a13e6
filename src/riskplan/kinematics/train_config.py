"""The options of MDN training (:func:`riskplan.kinematics.train`): architecture,
optimiser, schedule, validation split, precision and seed, as stored in ``model.json`` and in
training checkpoints."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from riskplan._validation import check_count
from riskplan.errors import InvalidInputError


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
