"""Numbers from text: one convention for comma-separated numbers, on command lines and in
text tables.

Every option that takes numbers (``--goal 0.01,0,0,0``, ``--arc 8,0``, ``--hidden 64,64``,
``-d "0,0,0,0;0.02,0,0,0"``) and every text table (a controls file, a ``--displacements``
file) is read by the functions here, with one convention:

* a **row** is numbers separated by commas: ``0.01, 0, -2e-3``. Spaces around a number are
  ignored; every field must hold a number, so an empty field (``1,,2``, a trailing comma)
  is an error, not skipped;
* **rows** are separated by ``;`` on a command line (``0,0,0,0;0.02,0,0,0``) and by line
  breaks in a file; an option that takes one row (:func:`parse_numbers`) rejects ``;``;
* a number is written as Python's :class:`float` reads it (``1e-3``, ``.5``, ``-2``) and
  must be finite (``nan`` and ``inf`` are errors); with ``integers=True`` a number is an
  integer literal (``64``, not ``64.0``).

A text table file (:func:`read_table`) adds: blank lines and lines starting with ``#``
are skipped, and so is one header line before the first row (a line none of whose fields
is a number, e.g. ``v,phi``).

Bad text raises :class:`~riskplan.errors.InvalidInputError` whose message starts with
``name`` (the option, e.g. ``--goal``), says what was expected and quotes what was given;
a bad file raises :class:`~riskplan.errors.DataFormatError` (a subclass) naming the file
and the line.
"""

from __future__ import annotations

import json
import math
import zipfile
import zlib
from pathlib import Path

import numpy as np

from riskplan.errors import DataFormatError, InvalidInputError

__all__ = ["TABLE_SUFFIXES", "parse_numbers", "parse_rows", "read_table"]

#: File name endings :func:`read_table` reads (case-insensitive).
TABLE_SUFFIXES = (".csv", ".txt", ".json", ".npy")


def _field(text: str, integers: bool) -> float | int:
    """One field of a row; ``ValueError`` with a short reason when it is not a number."""
    s = text.strip()
    if not s:
        raise ValueError("an empty field")
    if integers:
        try:
            return int(s)
        except ValueError:
            raise ValueError(f"{s!r} is not an integer") from None
    try:
        v = float(s)
    except ValueError:
        raise ValueError(f"{s!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{s!r} is not a finite number")
    return v


def _row(text: str, integers: bool) -> list:
    return [_field(f, integers) for f in text.split(",")]


def parse_numbers(
    text: str,
    name: str,
    *,
    count: int | None = None,
    integers: bool = False,
    allow_empty: bool = False,
) -> list:
    """One row of comma-separated numbers (module docstring): ``"0.01,0,0"`` -> ``[0.01, 0.0, 0.0]``.

    ``name`` starts every error message (the option, e.g. ``"--goal"``). ``count``: the
    number of values required. ``integers``: values are ``int`` (integer literals only).
    ``allow_empty``: an empty or blank ``text`` gives ``[]`` (e.g. ``--head-hidden ''``, no
    hidden layers) instead of an error. Raises :class:`InvalidInputError`.

    Parameters
    ----------
    text : str
        The row.
    name : str
        The option, for messages.
    count : int, optional
        The number of values required.
    integers : bool
        Values are ``int``.
    allow_empty : bool
        A blank ``text`` gives ``[]``.

    Returns
    -------
    list of float or list of int
        The values.
    """
    kind = "integers" if integers else "numbers"
    if not isinstance(text, str):
        raise InvalidInputError(f"{name}: expected comma-separated {kind}, got {text!r}")
    if not text.strip():
        if allow_empty and count in (None, 0):
            return []
        raise InvalidInputError(f"{name}: expected comma-separated {kind}, got {text!r}")
    if ";" in text:
        raise InvalidInputError(
            f"{name}: takes one row of comma-separated {kind}; ';' separates rows, got {text!r}"
        )
    try:
        values = _row(text, integers)
    except ValueError as exc:
        raise InvalidInputError(
            f"{name}: expected comma-separated {kind}, got {text!r} ({exc})"
        ) from None
    if count is not None and len(values) != count:
        raise InvalidInputError(
            f"{name}: expected {count} comma-separated {kind}, got {len(values)} in {text!r}"
        )
    return values


def parse_rows(text: str, name: str, *, columns: int | None = None) -> np.ndarray:
    """Rows of comma-separated numbers separated by ``;`` (module docstring):
    ``"0,0;0.02,0"`` -> float64 array ``(2, 2)``; one row gives ``(1, m)``.

    Every row must have the same length (``columns`` when given). Raises
    :class:`InvalidInputError` naming ``name``.

    Parameters
    ----------
    text : str
        The rows.
    name : str
        The option, for messages.
    columns : int, optional
        The row length required.

    Returns
    -------
    numpy.ndarray
        ``(N, m)`` float64.
    """
    if not isinstance(text, str) or not text.strip():
        raise InvalidInputError(
            f"{name}: expected rows of comma-separated numbers ('d1,d2,...;d1,d2,...'), got {text!r}"
        )
    rows = []
    for i, part in enumerate(text.split(";")):
        try:
            rows.append(_row(part, False))
        except ValueError as exc:
            raise InvalidInputError(
                f"{name}: row {i + 1} of {text!r} is not a row of comma-separated numbers ({exc})"
            ) from None
    lengths = {len(r) for r in rows}
    if len(lengths) != 1:
        raise InvalidInputError(
            f"{name}: expected rows of equal length ('d1,d2,...;d1,d2,...'), got lengths "
            f"{[len(r) for r in rows]} in {text!r}"
        )
    if columns is not None and rows[0] and len(rows[0]) != columns:
        raise InvalidInputError(
            f"{name}: expected {columns} comma-separated numbers per row, got {len(rows[0])}"
        )
    return np.asarray(rows, dtype=np.float64)


def read_table(path, name: str, *, key: str | None = None) -> np.ndarray:
    """A table of numbers from a file, by its ending (:data:`TABLE_SUFFIXES`):

    * ``.csv`` / ``.txt``: one row per line, comma-separated (module docstring): blank
      lines and ``#`` lines are skipped, and one header line before the first row;
    * ``.json``: a list of rows ``[[...], ...]``, one row ``[...]``, or (with ``key``) an
      object holding the list under ``key``;
    * ``.npy``: a NumPy array (no pickles);
    * ``.npz`` (only with ``key``): the array stored under ``key`` (e.g. the ``controls`` of
      the ``selected.npz`` that ``riskplan plan tissue`` writes).

    Returns a float64 array: ``(N, m)`` from a text file, as stored (1-D or 2-D) from JSON
    and ``.npy``. Checks only that it holds finite numbers in a 1-D or non-empty 2-D
    table; the caller checks the shape it needs. Raises :class:`DataFormatError` naming
    ``name`` and the file (and the line, for text).

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    name : str
        The option, for messages.
    key : str, optional
        The entry of a JSON object or ``.npz`` file.

    Returns
    -------
    numpy.ndarray
        The table, float64.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    suffixes = TABLE_SUFFIXES + ((".npz",) if key is not None else ())
    if suffix not in suffixes:
        raise DataFormatError(
            f"{name}: {path.name}: expected a file ending in {', '.join(suffixes)}"
        )
    if not path.is_file():
        raise DataFormatError(f"{name}: no such file {str(path)!r}")
    if suffix == ".npz":
        try:
            with np.load(path, allow_pickle=False) as npz:
                files = list(npz.files)
                rows = npz[key] if key in files else None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise DataFormatError(
                f"{name}: cannot read {path.name} as a .npz file ({exc})"
            ) from exc
        if rows is None:
            raise DataFormatError(
                f"{name}: {path.name} holds no {key!r} array (it has {', '.join(files) or 'none'})"
            )
    elif suffix == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as exc:
            raise DataFormatError(
                f"{name}: cannot read {path.name} as a .npy array ({exc})"
            ) from exc
        rows = arr
    else:
        try:
            text = path.read_text(encoding="utf-8-sig")  # a spreadsheet's byte-order mark
        except UnicodeDecodeError as exc:
            raise DataFormatError(f"{name}: {path.name} is not UTF-8 text ({exc})") from exc
        if suffix == ".json":
            try:
                rows = json.loads(text)
            except json.JSONDecodeError as exc:
                raise DataFormatError(f"{name}: {path.name} is not valid JSON ({exc})") from exc
            if isinstance(rows, dict):
                if key is None or key not in rows:
                    raise DataFormatError(
                        f"{name}: {path.name} holds an object; expected a list of rows"
                        + (f" or an object with a {key!r} key" if key else "")
                    )
                rows = rows[key]
        else:
            rows = _text_rows(text, name, path.name)
    try:
        arr = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataFormatError(
            f"{name}: {path.name} rows have different lengths or hold non-numbers"
        ) from exc
    if arr.ndim not in (1, 2) or arr.size == 0:
        raise DataFormatError(
            f"{name}: {path.name} must hold one row or a non-empty (N, m) table, got shape {arr.shape}"
        )
    bad = np.flatnonzero(~np.isfinite(arr.reshape(len(arr), -1)).all(axis=1))
    if bad.size:
        raise DataFormatError(f"{name}: {path.name} row {int(bad[0]) + 1} contains NaN or inf")
    return arr


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def _text_rows(text: str, name: str, filename: str) -> list[list[float]]:
    rows: list[list[float]] = []
    header_seen = False
    for i, line in enumerate(text.splitlines()):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(";", ",").split(",")
        if not rows and not header_seen and not any(_is_number(f) for f in fields):
            header_seen = True  # one header line (no field is a number) before the data
            continue
        try:
            if ";" in line:
                raise ValueError("';' inside a line; a file has one row per line")
            rows.append(_row(line, False))
        except ValueError as exc:
            raise DataFormatError(
                f"{name}: {filename} line {i + 1} is not a row of comma-separated numbers ({exc})"
            ) from None
        if len(rows[-1]) != len(rows[0]):
            raise DataFormatError(
                f"{name}: {filename} line {i + 1} has {len(rows[-1])} numbers, the first row "
                f"{len(rows[0])}"
            )
    return rows
