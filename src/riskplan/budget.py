"""One work-budget rule: requests whose estimate exceeds a ceiling are refused before any work.

A request (a sample count, a number of steps, a resolution) is turned into an estimate by the
code that knows its cost, and checked here, once, against two ceilings:

* **memory**: the bytes the request would hold at once (its arrays, its stored results).
  Ceiling: ``RISKPLAN_MAX_MEMORY`` (``"64G"``, ``"512M"``, bytes), default the smaller of
  16 GiB and half the machine's physical memory.
* **time**: a *lower bound* on the seconds the request needs (units of work times the least
  time one unit has been measured to take on a fast machine), so a refusal never rests on a
  pessimistic guess. Ceiling: ``RISKPLAN_MAX_HOURS``, default 24 hours.

The CLI's ``--max-memory`` and ``--max-hours`` (before the command: ``riskplan --max-hours 72
plan tissue ...``) set these for one run. A refusal is a
:class:`~riskplan.errors.BudgetError` naming the estimate, the ceiling, the option that
set the request and how to raise the ceiling.
"""

from __future__ import annotations

import math
import os
import re

from riskplan.errors import BudgetError, InvalidInputError

__all__ = [
    "MEMORY_ENV",
    "TIME_ENV",
    "check_budget",
    "format_bytes",
    "memory_ceiling",
    "parse_bytes",
    "time_ceiling",
]

MEMORY_ENV = "RISKPLAN_MAX_MEMORY"
TIME_ENV = "RISKPLAN_MAX_HOURS"
DEFAULT_MEMORY = 16 * 2**30
DEFAULT_HOURS = 24.0

_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def parse_bytes(text, name: str = MEMORY_ENV) -> int:
    """``"16G"``, ``"512M"``, ``"2.5T"`` or a plain number of bytes -> bytes (binary units).

    Parameters
    ----------
    text : str or float
        The size.
    name : str
        What it sets, for messages.

    Returns
    -------
    int
        Bytes (K, M, G, T are powers of 1024).
    """
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([KMGT]?)(?:i?B)?\s*", str(text))
    if not m:
        raise InvalidInputError(f"{name}: expected a size such as 16G or 512M, got {text!r}")
    value = float(m.group(1)) * _UNITS[m.group(2).upper()]
    if not (math.isfinite(value) and value > 0):
        raise InvalidInputError(f"{name}: expected a positive size, got {text!r}")
    return int(value)


def format_bytes(n: float) -> str:
    """``n`` bytes in the largest binary unit that keeps the number >= 1 (``"24.0 GiB"``).

    Parameters
    ----------
    n : float
        Bytes.

    Returns
    -------
    str
        The size with its unit.
    """
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n:.0f} B"


def _physical_memory() -> int | None:
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, OSError, ValueError):  # pragma: no cover - not POSIX
        return None


def memory_ceiling() -> int:
    """Bytes a single request may hold (``RISKPLAN_MAX_MEMORY``, module docstring).

    Returns
    -------
    int
        Bytes: ``RISKPLAN_MAX_MEMORY``, else the default capped at half the physical memory.
    """
    text = os.environ.get(MEMORY_ENV)
    if text:
        return parse_bytes(text)
    phys = _physical_memory()
    # half: the request is not alone (the interpreter, its libraries, other processes)
    return min(DEFAULT_MEMORY, phys // 2) if phys else DEFAULT_MEMORY


def time_ceiling() -> float:
    """Seconds a single request may need at least (``RISKPLAN_MAX_HOURS``, module docstring).

    Returns
    -------
    float
        Seconds: ``RISKPLAN_MAX_HOURS`` × 3600, else the default.
    """
    text = os.environ.get(TIME_ENV)
    if not text:
        return DEFAULT_HOURS * 3600.0
    try:
        hours = float(text)
    except ValueError:
        hours = float("nan")
    if not (math.isfinite(hours) and hours > 0):
        raise InvalidInputError(f"{TIME_ENV}: expected a positive number of hours, got {text!r}")
    return hours * 3600.0


def _duration(seconds: float) -> str:
    if seconds >= 2 * 86400:
        return f"{seconds / 86400:.3g} days"
    if seconds >= 2 * 3600:
        return f"{seconds / 3600:.3g} hours"
    return f"{seconds:.3g} s"


def check_budget(what: str, option: str, *, nbytes: float = 0.0, seconds: float = 0.0) -> None:
    """Refuse a request whose estimate exceeds a ceiling (the one budget rule).

    Parameters
    ----------
    what : the request in words (``"50 000 000 000 Monte Carlo samples"``).
    option : the argument or CLI option that set it (``"--executions"``).
    nbytes : memory the request would hold at once (bytes); ``inf``/``nan`` always refused.
    seconds : a lower bound on its run time (seconds).

    Raises
    ------
    BudgetError
        Naming the estimate, the ceiling and how to raise it.
    """
    nbytes, seconds = float(nbytes), float(seconds)
    ceiling = memory_ceiling()
    if not nbytes <= ceiling:  # also NaN
        raise BudgetError(
            f"{option}: {what} would need about {format_bytes(nbytes)} of memory, more than "
            f"the {format_bytes(ceiling)} budget; lower {option}, or raise the budget with "
            f"--max-memory (or {MEMORY_ENV}) if the machine has the memory"
        )
    limit = time_ceiling()
    if not seconds <= limit:
        raise BudgetError(
            f"{option}: {what} would take at least {_duration(seconds)}, more than the "
            f"{_duration(limit)} budget; lower {option}, or raise the budget with --max-hours "
            f"(or {TIME_ENV})"
        )
