"""Argument checks used at public boundaries (inner functions trust their callers)."""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence

import numpy as np

from riskplan.errors import InvalidInputError, NumericalError


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


def integer_words(minimum: int | None = 0, maximum: int | None = None) -> str:
    """How riskplan says which integers it accepts: ``"a positive integer"``,
    ``"a non-negative integer"``, ``"an integer >= 2"``, ``"an integer in [0, 64]"`` or
    (``minimum=None``) ``"an integer"``."""
    if minimum is None:
        return "an integer"
    if maximum is not None:
        return f"an integer in [{minimum}, {maximum}]"
    if minimum == 0:
        return "a non-negative integer"
    if minimum == 1:
        return "a positive integer"
    return f"an integer >= {minimum}"


def check_count(
    value,
    name: str,
    minimum: int | None = 0,
    *,
    maximum: int | None = None,
    integral: bool = False,
    none: bool = False,
    noun: str = "",
    alternatives: str = "",
    error=InvalidInputError,
) -> int | None:
    """``value`` as an ``int`` if it is an integer (not a bool) in ``[minimum, maximum]``.

    The one check of integer arguments (counts, sizes, seeds, indices read from files).

    Parameters
    ----------
    value : object
        The argument.
    name : str
        What the message calls it (``"n_samples"``, ``"--seed"``, ``"'disks.count'"``).
    minimum, maximum : int or None
        The accepted range; ``None`` is unbounded on that side (``maximum`` is used only with
        a ``minimum``).
    integral : bool
        Also accept a finite real number with an integral value (``640.0``), returned as
        ``int``.
    none : bool
        Accept ``None`` (returned as it is); the message says "or None".
    noun : str
        What the integer counts, for the message (``"pixel count"``).
    alternatives : str
        Other accepted kinds the caller handles before this check, for the message
        (``"a torch.Generator"``).
    error : callable
        Called with the message to build the exception raised (default
        :class:`InvalidInputError`; e.g. a :class:`~riskplan.errors.DataFormatError` that
        names a file).

    Returns
    -------
    int or None
        ``value`` as a Python ``int`` (``None`` when ``none`` and ``value is None``).

    Raises
    ------
    InvalidInputError
        (or what ``error`` builds) ``"{name}: expected a positive integer, got 2.5"``.
    """
    if none and value is None:
        return None
    ok = False
    if isinstance(value, bool):
        ok = False
    elif isinstance(value, numbers.Integral):
        ok = True
    elif integral and isinstance(value, numbers.Real):
        ok = math.isfinite(float(value)) and float(value).is_integer()
    if ok:
        v = int(value)
        ok = minimum is None or (v >= minimum and (maximum is None or v <= maximum))
    if not ok:
        words = integer_words(minimum, maximum) + (f" {noun}" if noun else "")
        others = [w for w in (alternatives, "None" if none else "") if w]
        if others:
            words = ", ".join([words, *others[:-1]]) + f" or {others[-1]}"
        raise error(f"{name}: expected {words}, got {value!r}")
    return v


def check_counts(values: dict, minimum: int = 0, **kwargs) -> dict[str, int]:
    """:func:`check_count` on each ``name: value`` of ``values``; returns the ``int`` values."""
    return {name: check_count(v, name, minimum, **kwargs) for name, v in values.items()}


def check_count_list(values, name: str, minimum: int = 1) -> tuple[int, ...]:
    """A non-empty sequence of integers ``>= minimum`` (integral floats accepted), as a tuple of
    ``int``; else :class:`InvalidInputError` naming ``name`` and showing the whole sequence."""
    plural = integer_words(minimum).split(" ", 1)[1].replace("integer", "integers", 1)
    try:
        items = () if isinstance(values, str | bytes) else tuple(values)
        if not items:
            raise InvalidInputError(name)
        return tuple(check_count(v, name, minimum, integral=True) for v in items)
    except (TypeError, InvalidInputError):
        raise InvalidInputError(
            f"{name}: expected a non-empty list of {plural}, got {values!r}"
        ) from None


def seed_sequence(seed) -> np.random.SeedSequence:
    """``np.random.SeedSequence(seed)``, or :class:`InvalidInputError` naming ``seed`` where
    NumPy cannot seed from it (a negative integer, a float, a string)."""
    try:
        return np.random.SeedSequence(seed)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(
            f"seed: expected None or {integer_words(0)}, got {seed!r} ({exc})"
        ) from exc


def as_cells(value, name: str, nodes: int, corners: int, cell: str) -> np.ndarray:
    """A mesh's cells: a ``(T > 0, corners)`` array of node indices in ``[0, nodes)``, every
    node used by some cell; integral floats are accepted.

    Parameters
    ----------
    value : array_like
        The cells.
    name : str
        What the messages call them (``"triangles"``).
    nodes : int
        The number of nodes.
    corners : int
        Nodes per cell (3 for a triangle, 4 for a tetrahedron).
    cell : str
        The cell's name, for the message about unused nodes (``"triangle"``).

    Returns
    -------
    numpy.ndarray
        ``(T, corners)`` int64.
    """
    c = np.asarray(value)
    if c.ndim != 2 or c.shape[1] != corners or c.shape[0] == 0:
        raise InvalidInputError(f"{name}: expected shape (T>0, {corners}), got {c.shape}")
    if not np.issubdtype(c.dtype, np.integer):
        if not np.all(np.isfinite(c)) or np.any(c != np.round(c)):
            raise InvalidInputError(f"{name}: expected integer node indices")
    c = c.astype(np.int64)
    if c.min() < 0 or c.max() >= nodes:
        raise InvalidInputError(f"{name}: node indices must lie in [0, {nodes - 1}]")
    used = np.zeros(nodes, dtype=bool)
    used[c.ravel()] = True
    if not used.all():
        raise InvalidInputError(
            f"nodes: nodes {np.flatnonzero(~used)[:10].tolist()} belong to no {cell}"
        )
    return c


def check_instance(value, cls: type, name: str):
    """``value`` if it is a ``cls``, else :class:`InvalidInputError`
    ``"{name}: expected a {cls.__name__}, got {type(value).__name__}"``."""
    if not isinstance(value, cls):
        raise InvalidInputError(f"{name}: expected a {cls.__name__}, got {type(value).__name__}")
    return value


def check_choice(value, choices, name: str):
    """``value`` if it is one of ``choices``, else :class:`InvalidInputError` listing them."""
    if value not in choices:
        raise InvalidInputError(f"{name}: expected one of {tuple(choices)}, got {value!r}")
    return value


def check_workers(workers) -> int | None:
    """``workers`` as riskplan reads it everywhere: ``None`` (one per core, capped at the
    cores by :func:`riskplan.parallel.effective_workers`) or an integer ``>= 1``; anything
    else raises :class:`InvalidInputError` naming ``workers``."""
    if workers is None:
        return None
    if isinstance(workers, bool) or not isinstance(workers, int | np.integer) or workers < 1:
        raise InvalidInputError(
            f"workers: expected {integer_words(1)} (or None for all cores), got {workers!r}"
        )
    return int(workers)


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
            f"seed: expected None, {integer_words(0)}, a SeedSequence or a Generator, "
            f"got {seed!r} ({exc})"
        ) from exc


# --- matrices of the control stage (deformable paper IV-C, IV-D) ---------------------------


def per_step(value, name: str, T: int, shape: tuple[int, int]) -> np.ndarray:
    """``value`` as a ``(T, *shape)`` array: a constant ``shape`` matrix is repeated for every step."""
    arr = as_array(value, name, min_ndim=2)
    if arr.shape == shape:
        return np.broadcast_to(arr, (T, *shape))
    if arr.shape != (T, *shape):
        raise InvalidInputError(f"{name}: expected shape {shape} or {(T, *shape)}, got {arr.shape}")
    return arr


def check_psd(mats: np.ndarray, name: str, *, definite: bool) -> None:
    """Raise unless every ``(..., n, n)`` matrix is symmetric positive (semi-)definite."""
    scale = max(1.0, float(np.abs(mats).max()) if mats.size else 1.0)
    if not np.allclose(mats, np.swapaxes(mats, -1, -2), rtol=1e-10, atol=1e-12 * scale):
        raise InvalidInputError(f"{name}: expected symmetric matrices")
    w = np.linalg.eigvalsh(0.5 * (mats + np.swapaxes(mats, -1, -2)))
    lo = float(w.min()) if w.size else 0.0
    if definite and lo <= 1e-12 * scale:
        raise InvalidInputError(
            f"{name}: expected positive definite matrices (smallest eigenvalue {lo:.3g})"
        )
    if not definite and lo < -1e-12 * scale:
        raise InvalidInputError(
            f"{name}: expected positive semi-definite matrices (smallest eigenvalue {lo:.3g})"
        )


def check_dynamics(A, B=None) -> tuple[np.ndarray, np.ndarray | None]:
    """``A (T, p, p)`` and ``B (T, p, q)`` checked against each other."""
    A = as_array(A, "A", min_ndim=3)
    if A.ndim != 3 or A.shape[1] != A.shape[2]:
        raise InvalidInputError(f"A: expected shape (T, p, p), got {A.shape}")
    if B is None:
        return A, None
    B = as_array(B, "B", min_ndim=3)
    if B.ndim != 3 or B.shape[:2] != A.shape[:2]:
        raise InvalidInputError(f"B: expected shape ({A.shape[0]}, {A.shape[1]}, q), got {B.shape}")
    return A, B


def raise_overflow(what: str, step: int, cause: Exception | None = None):
    """Raise :class:`NumericalError` for a recursion that left float64's range at ``step``."""
    raise NumericalError(
        f"{what} overflowed float64 at step {step} (non-finite gain or covariance); the "
        "matrices are finite but too large or too unstable over this horizon",
        step=step,
    ) from cause
