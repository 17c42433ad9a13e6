"""Argument checks used at public boundaries (inner functions trust their callers)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from riskplan.errors import InvalidInputError


def as_array(
    value,
    name: str,
    *,
    shape: Sequence[int | None] | None = None,
    min_ndim: int | None = None,
    last_dim: int | None = None,
    dtype=np.float64,
    finite: bool = True,
) -> np.ndarray:
    """Convert ``value`` to an array and check it.

    ``shape`` entries of ``None`` match any length. ``last_dim`` checks only the
    trailing axis (for batched inputs ``(..., d)``). Raises
    :class:`InvalidInputError` naming ``name`` and what was expected.
    """
    if np.dtype(dtype).kind == "f" and np.iscomplexobj(value):
        # asarray(..., float) would drop the imaginary part with only a warning
        raise InvalidInputError(f"{name}: expected real numbers, got complex values")
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(
            f"{name}: cannot convert to a {np.dtype(dtype).name} array ({exc})"
        ) from exc
    if shape is not None:
        if arr.ndim != len(shape) or any(
            s is not None and s != a for s, a in zip(shape, arr.shape)
        ):
            want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
            raise InvalidInputError(f"{name}: expected shape {want}, got {arr.shape}")
    if min_ndim is not None and arr.ndim < min_ndim:
        raise InvalidInputError(
            f"{name}: expected at least {min_ndim} dimensions, got shape {arr.shape}"
        )
    if last_dim is not None and (arr.ndim == 0 or arr.shape[-1] != last_dim):
        raise InvalidInputError(
            f"{name}: expected last dimension {last_dim}, got shape {arr.shape}"
        )
    if finite and np.issubdtype(arr.dtype, np.floating) and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise InvalidInputError(
            f"{name}: contains NaN or inf (first at index {tuple(int(i) for i in bad)})"
        )
    return arr


def check_range(
    arr, name: str, low=None, high=None, *, low_inclusive=True, high_inclusive=True
) -> None:
    """Raise :class:`InvalidInputError` if any element of ``arr`` leaves ``[low, high]``.

    ``low`` / ``high`` may be arrays broadcasting against ``arr`` (per-element limits).
    """
    a = np.asarray(arr)
    if low is not None:
        bad = (a < low) if low_inclusive else (a <= low)
        _raise_first(a, bad, low, name, ">=" if low_inclusive else ">")
    if high is not None:
        bad = (a > high) if high_inclusive else (a >= high)
        _raise_first(a, bad, high, name, "<=" if high_inclusive else "<")


def _raise_first(a, bad, limit, name: str, op: str) -> None:
    """:class:`InvalidInputError` naming the first element of ``a`` where ``bad`` holds."""
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        lim = np.broadcast_to(limit, a.shape)[idx]
        raise InvalidInputError(
            f"{name}: value {a[idx]:.6g} at index {idx} violates {name} {op} {lim:.6g}"
        )


def check_count(value, name: str, minimum: int = 0) -> int:
    """``value`` as an ``int`` if it is an integer (not a bool) ``>= minimum``, else
    :class:`InvalidInputError` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise InvalidInputError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def as_generator(seed) -> np.random.Generator:
    """``seed`` may be ``None``, an int, a ``SeedSequence`` or a ``Generator``.

    Anything NumPy cannot seed from (a negative integer, a float, a string) raises
    :class:`InvalidInputError` naming ``seed``.
    """
    if isinstance(seed, np.random.Generator):
        return seed
    try:
        return np.random.default_rng(seed)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(
            f"seed: expected None, a non-negative integer, a SeedSequence or a Generator, "
            f"got {seed!r} ({exc})"
        ) from exc
