"""Controls files: a ``(T, q)`` table of controls, one step per row, for a scenario
(``riskplan tissue simulate --controls FILE``).

``q = 2`` for the needle (``v, phi``), ``q = 6`` for the manipulation scenario
(``F1x, F1y, F2x, F2y, F3x, F3y``). The file is read by :func:`riskplan.parsing.read_table`:

* ``.csv`` / ``.txt``: comma-separated numbers, one step per line; blank lines, lines
  starting with ``#`` and one header line before the data (e.g. ``v,phi``) are skipped;
* ``.json``: a list of rows ``[[v, phi], ...]`` or an object ``{"controls": [[...], ...]}``;
* ``.npy``: a ``(T, q)`` array;
* ``.npz``: the array under ``controls``, e.g. the ``selected.npz`` of ``riskplan plan tissue``
  (so ``riskplan tissue simulate --controls OUT/selected.npz`` replays the selected plan open
  loop).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from riskplan.errors import DataFormatError
from riskplan.parsing import read_table

__all__ = ["read_controls"]


def read_controls(path, control_dim: int, bounds=None) -> np.ndarray:
    """Read a float64 controls table (module docstring).

    Raises :class:`~riskplan.errors.DataFormatError` (a missing or unreadable file, rows of
    different lengths, non-numbers, NaN or inf, the wrong column count, a value outside
    ``bounds``).

    Parameters
    ----------
    path : str or path
    control_dim : int
        Columns expected (the scenario's ``q``).
    bounds : array_like, (control_dim, 2), optional
        When given, every row is checked against them here, before any simulation, and the
        first offending row and column are named (counted from 1).

    Returns
    -------
    numpy.ndarray, (T, control_dim)
    """
    path = Path(path)
    arr = read_table(path, "controls", key="controls")
    if path.suffix.lower() == ".npz":
        with np.load(path, allow_pickle=False) as npz:
            several = "control_offsets" in npz.files
        if several:  # candidates.npz: every candidate's controls, one after the other
            raise DataFormatError(
                f"controls: {path.name} holds several plans (control_offsets); expected one "
                "plan, e.g. the selected.npz of `riskplan plan tissue`"
            )
    if arr.ndim != 2:
        raise DataFormatError(
            f"controls: expected a non-empty (T, {control_dim}) table, got shape {arr.shape}"
        )
    if arr.shape[1] != control_dim:
        raise DataFormatError(
            f"controls: {path.name} has {arr.shape[1]} columns per row, expected {control_dim}"
        )
    if bounds is not None:
        b = np.asarray(bounds, dtype=np.float64)
        out = (arr < b[:, 0]) | (arr > b[:, 1])
        if out.any():
            r, c = (int(i) for i in np.argwhere(out)[0])
            raise DataFormatError(
                f"controls: {path.name} row {r + 1} column {c + 1} is {arr[r, c]:.6g}, outside "
                f"the bounds [{b[c, 0]:.6g}, {b[c, 1]:.6g}]"
            )
    return arr
