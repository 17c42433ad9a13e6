"""Timing helpers for benchmarks: the median of repeats after warm-up, and where a
benchmark ran (CPU, cores, thread settings), which ``riskplan bench`` adds to every
JSON object it prints."""

from __future__ import annotations

import os
import platform
import sys
import time
from collections.abc import Callable

#: Environment variables that set thread counts of the numeric libraries.
THREAD_ENV_VARS = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "NUMBA_NUM_THREADS",
)


def median_time(
    fn: Callable[[], object], repeats: int = 50, warmup: int = 3, inner: int = 1
) -> float:
    """Median wall-clock seconds of one call to ``fn`` (``inner`` calls per sample)."""
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(inner):
            fn()
        samples.append((time.perf_counter() - t0) / inner)
    samples.sort()
    return samples[len(samples) // 2]


def cpu_model() -> str:
    """The CPU's model name (``model name`` in ``/proc/cpuinfo`` on Linux, else what
    :mod:`platform` reports)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and value.strip():
                    return value.strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def thread_settings() -> dict:
    """Thread settings in effect now: the ``THREAD_ENV_VARS`` (``None`` when unset), the
    BLAS/OpenMP pools loaded in this process (``threadpoolctl``: library and thread
    count) and torch's intra-op threads when torch is loaded."""
    out: dict = {var: os.environ.get(var) for var in THREAD_ENV_VARS}
    from threadpoolctl import threadpool_info

    out["pools"] = [
        {
            "library": p.get("internal_api", p.get("prefix")),
            "api": p.get("user_api"),
            "num_threads": p.get("num_threads"),
        }
        for p in threadpool_info()
    ]
    torch = sys.modules.get("torch")
    out["torch"] = torch.get_num_threads() if torch is not None else None
    return out


def machine_info() -> dict:
    """Where a benchmark ran, as a JSON-ready dict: ``cpu_model``, ``cpu_count``
    (logical cores of the machine), ``cpus_usable`` (cores this process may run on) and
    ``threads`` (:func:`thread_settings`)."""
    try:
        usable = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        usable = os.cpu_count()
    return {
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpus_usable": usable,
        "threads": thread_settings(),
    }
