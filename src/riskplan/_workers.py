"""The worker side of :mod:`riskplan.parallel`'s process pools: the chunk runner, the worker
start (one thread per library, Ctrl-C left to the parent, a watchdog that ends the worker once
the parent is gone) and stopping a pool. Kept apart so that each file stays within the size
measure; :mod:`riskplan.parallel` is the interface."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any


def run_chunk(fn: Callable, chunk: Sequence[tuple[int, Any]]) -> list[tuple[int, Any]]:
    return [(i, fn(item)) for i, item in chunk]


PARENT_POLL_SECONDS = 0.25


def parent_gone(parent_pid: int, ppid: int) -> bool:
    """True when the pool's parent has exited (or our own parent, the forkserver, has)."""
    if os.getppid() != ppid:
        return True
    try:
        os.kill(parent_pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # pragma: no cover - alive, another user
        return False
    try:  # a killed parent that its own parent has not reaped yet is a zombie
        return stat_fields(parent_pid)[0] in (b"Z", b"X")
    except OSError:
        return False


def stat_fields(pid: int) -> list[bytes]:
    """The fields of Linux's ``/proc/<pid>/stat`` from the third (the state) on: the name
    (field 2) may hold spaces and parentheses, so the split starts after its last ``)``.
    Raises ``OSError`` without that file."""
    with open(f"/proc/{pid}/stat", "rb") as fh:
        return fh.read().rsplit(b")", 1)[1].split()


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds process ``pid`` has used so far: fields 14 and 15 of Linux's
    ``/proc/<pid>/stat`` (clock ticks); ``None`` without that file (another system, or the
    process is gone). A pool's workers are children of the forkserver, not of this process,
    so ``resource.getrusage(RUSAGE_CHILDREN)`` never counts them."""
    try:
        fields = stat_fields(pid)
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def watch_parent(parent_pid: int, ppid: int) -> None:
    import time

    while not parent_gone(parent_pid, ppid):
        time.sleep(PARENT_POLL_SECONDS)
    os._exit(1)  # no cleanup to do: results belong to the parent, which is gone


def init_worker(parent_pid: int) -> None:
    """Worker start: one thread per library, Ctrl-C left to the parent, exit with the parent."""
    import signal
    import threading

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(
        target=watch_parent,
        args=(parent_pid, os.getppid()),
        daemon=True,
        name="riskplan-parent-watch",
    ).start()
    limit_threads()


def pool_processes(pool) -> list:
    """The worker processes of a ``ProcessPoolExecutor`` ``pool`` (empty when it has none)."""
    # ProcessPoolExecutor has no public way to reach its workers; its worker table is stable
    # across CPython 3.9-3.13.
    return list((getattr(pool, "_processes", None) or {}).values())


def terminate_pool(pool) -> None:
    """Cancel what has not started and stop the workers now (their results are not wanted)."""
    procs = pool_processes(pool)  # taken before shutdown, which clears the table
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        try:
            proc.terminate()
        except Exception:  # already gone
            pass
    for proc in procs:
        proc.join(timeout=5)


def limit_threads() -> None:
    # Worker processes share few cores: one BLAS/torch thread each avoids oversubscription.
    from riskplan.threads import limit_process_threads

    limit_process_threads(1)
