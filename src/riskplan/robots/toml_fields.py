"""Typed reads of a robot file's fields (a parsed TOML table): numbers, vectors, integers,
tables and unknown keys, each refused with a :class:`~riskplan.errors.RobotDescriptionError`
that names the key (``backbone.step``) and, for an unknown key, the known one it is closest to.
"""

from __future__ import annotations

import math

from riskplan._validation import check_count
from riskplan.errors import RobotDescriptionError

__all__ = [
    "check_unknown_keys",
    "field_integer",
    "field_number",
    "field_table",
    "field_vector",
    "suggest_key",
]


def field_number(
    table: dict, key: str, path: str, *, default=None, positive=False, nonneg=False, allow_inf=False
) -> float:
    """``table[key]`` as a float (``default`` when missing and not None), finite unless
    ``allow_inf``, and ``> 0`` / ``>= 0`` when asked; ``path`` is the table's key.

    Parameters
    ----------
    table : dict
        A parsed TOML table.
    key : str
        The key to read.
    path : str
        The table's dotted key, for messages (``""`` at the top).
    default : float, optional
        Value when the key is missing (else a missing key is an error).
    positive, nonneg : bool
        Require ``> 0`` / ``>= 0``.
    allow_inf : bool
        Accept ``±inf``.

    Returns
    -------
    float
        The value; :class:`~riskplan.errors.RobotDescriptionError` naming the key otherwise.
    """
    full = f"{path}.{key}" if path else key
    if key not in table:
        if default is None:
            raise RobotDescriptionError(f"robot description: missing key '{full}'", key=full)
        return float(default)
    val = table[key]
    if isinstance(val, bool) or not isinstance(val, (int, float)):
        raise RobotDescriptionError(
            f"robot description: '{full}' must be a number, got {val!r}", key=full
        )
    val = float(val)
    if math.isnan(val) or (math.isinf(val) and not allow_inf):
        raise RobotDescriptionError(
            f"robot description: '{full}' must be finite, got {val}", key=full
        )
    if positive and not val > 0:
        raise RobotDescriptionError(f"robot description: '{full}' must be > 0, got {val}", key=full)
    if nonneg and not val >= 0:
        raise RobotDescriptionError(
            f"robot description: '{full}' must be >= 0, got {val}", key=full
        )
    return val


def field_vector(
    table: dict, key: str, path: str, n: int | None, *, default=None
) -> tuple[float, ...]:
    """``table[key]``: a non-empty list of ``n`` (any number if None) finite numbers, as a
    tuple of floats (``default`` when missing and not None).

    Parameters
    ----------
    table : dict
        A parsed TOML table.
    key : str
        The key to read.
    path : str
        The table's dotted key, for messages.
    n : int or None
        Required length (None: any non-empty length).
    default : sequence of float, optional
        Value when the key is missing.

    Returns
    -------
    tuple of float
        The finite numbers.
    """
    full = f"{path}.{key}" if path else key
    if key not in table:
        if default is None:
            raise RobotDescriptionError(f"robot description: missing key '{full}'", key=full)
        return tuple(float(v) for v in default)
    val = table[key]
    if not isinstance(val, list) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in val
    ):
        raise RobotDescriptionError(
            f"robot description: '{full}' must be a list of numbers, got {val!r}", key=full
        )
    if n is not None and len(val) != n:
        raise RobotDescriptionError(
            f"robot description: '{full}' must have {n} entries, got {len(val)}", key=full
        )
    if n is None and len(val) == 0:
        raise RobotDescriptionError(f"robot description: '{full}' must not be empty", key=full)
    out = tuple(float(v) for v in val)
    if not all(math.isfinite(v) for v in out):
        raise RobotDescriptionError(
            f"robot description: '{full}' must be finite, got {val!r}", key=full
        )
    return out


def field_integer(value, key: str, low: int, high: int) -> int:
    """``value`` of ``key`` as an ``int`` in ``[low, high]``, else
    :class:`RobotDescriptionError` naming the key.

    Parameters
    ----------
    value : object
        The value read.
    key : str
        Its key, for messages.
    low, high : int
        Inclusive bounds.

    Returns
    -------
    int
        The value.
    """
    return check_count(
        value,
        f"robot description: {key!r}",
        low,
        maximum=high,
        error=lambda msg: RobotDescriptionError(msg, key=key),
    )


def field_table(doc: dict, key: str, *, required=True) -> dict:
    """The table ``doc[key]`` (``{}`` when missing and not ``required``).

    Parameters
    ----------
    doc : dict
        A parsed TOML document or table.
    key : str
        The sub-table's key.
    required : bool
        A missing table is an error (else ``{}``).

    Returns
    -------
    dict
        The sub-table.
    """
    if key not in doc:
        if required:
            raise RobotDescriptionError(f"robot description: missing table '[{key}]'", key=key)
        return {}
    t = doc[key]
    if not isinstance(t, dict):
        raise RobotDescriptionError(f"robot description: '{key}' must be a table", key=key)
    return t


def suggest_key(key: str, known) -> str:
    """``" (did you mean 'x'?)"`` naming the known key closest to ``key``, or ``""``.

    Closeness is ``difflib.get_close_matches`` on the lower-cased names (cut-off 0.6),
    falling back to a known key that contains ``key`` or is contained in it.

    Parameters
    ----------
    key : str
        The unknown key.
    known : iterable of str
        The known keys.

    Returns
    -------
    str
        The suggestion, or ``""``.
    """
    import difflib

    known = sorted(known)
    lower = {k.lower(): k for k in known}
    hits = difflib.get_close_matches(key.lower(), list(lower), n=1, cutoff=0.6)
    if not hits:
        hits = [k for k in lower if key.lower() in k or (k in key.lower() and len(k) > 2)]
    return f" (did you mean '{lower[hits[0]]}'?)" if hits else ""


def check_unknown_keys(
    table: dict, allowed: set[str], path: str, *, what="robot description"
) -> None:
    """Refuse the first key of ``table`` not in ``allowed``, suggesting the closest one.

    Parameters
    ----------
    table : dict
        A parsed TOML table.
    allowed : set of str
        Its known keys.
    path : str
        The table's dotted key, for messages.
    what : str
        What the table belongs to, for messages.
    """
    for k in table:
        if k not in allowed:
            full = f"{path}.{k}" if path else k
            raise RobotDescriptionError(
                f"{what}: unknown key '{full}'{suggest_key(k, allowed)}", key=full
            )
