"""The MDN's normalisation (MDN paper section III): affine maps of the inputs (tendon
displacements, any base motion) and of the points, fitted on the training split, so the
network works in units of order one; NLLs in metres are those in normalised units plus
``sum log output_scale``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Normalisation:
    """Affine maps of inputs and points (fitted on the training split).

    The network sees ``(x - input_mean) / input_scale`` for inputs ``x (..., m)`` and
    ``(p - output_centre) / output_scale`` for points ``p (..., d)`` (m).
    """

    input_mean: np.ndarray
    input_scale: np.ndarray
    output_centre: np.ndarray
    output_scale: np.ndarray

    @classmethod
    def fit(cls, displacements: np.ndarray, points: np.ndarray, angle_columns=()) -> Normalisation:
        """Inputs: mean/std per tendon (identity for ``angle_columns``: the network takes their
        cos and sin); points: mean/std per axis over all points.

        Parameters
        ----------
        displacements : numpy.ndarray, (N, m)
        points : numpy.ndarray, (N, P, d)
        angle_columns : sequence of int

        Returns
        -------
        Normalisation
        """
        im = displacements.mean(0)
        isd = displacements.std(0)
        isd = np.where(isd > 0, isd, 1.0)
        for a in angle_columns:
            im[a], isd[a] = 0.0, 1.0
        flat = points.reshape(-1, points.shape[-1])  # no float64 copy of a large cloud array
        oc = flat.mean(0, dtype=np.float64)
        osd = flat.std(0, dtype=np.float64)
        osd = np.where(osd > 0, osd, 1.0)
        return cls(im, isd, oc, osd)

    def to_json(self) -> dict:
        """The maps as JSON types, as stored in ``model.json`` and training checkpoints.

        Returns
        -------
        dict
            ``input_mean``, ``input_scale`` (lists of ``m``), ``output_centre``,
            ``output_scale`` (lists of ``d``; m).
        """
        return {
            k: np.asarray(getattr(self, k), dtype=np.float64).tolist()
            for k in ("input_mean", "input_scale", "output_centre", "output_scale")
        }

    @classmethod
    def from_json(cls, obj: dict) -> Normalisation:
        """Inverse of :meth:`to_json`.

        Parameters
        ----------
        obj : dict
            ``input_mean``, ``input_scale``, ``output_centre``, ``output_scale`` (lists).

        Returns
        -------
        Normalisation
            float64 arrays.
        """
        return cls(
            *(
                np.asarray(obj[k], dtype=np.float64)
                for k in ("input_mean", "input_scale", "output_centre", "output_scale")
            )
        )

    @property
    def log_scale_sum(self) -> float:
        """``sum log s``: NLL in metres = NLL in normalised units + this."""
        return float(np.log(self.output_scale).sum())
