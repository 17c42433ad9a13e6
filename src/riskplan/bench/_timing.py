"""Timing helpers for benchmarks (median of repeats, after warm-up)."""

from __future__ import annotations

import time
from collections.abc import Callable


def median_time(fn: Callable[[], object], repeats: int = 50, warmup: int = 3, inner: int = 1) -> float:
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
