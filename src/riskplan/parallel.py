"""Map independent tasks over a backend: ``serial``, ``local`` (process pool, default) or ``ray``.

Results never depend on the backend: tasks must take their randomness from their
arguments (use :func:`spawn_seeds` to derive one seed per task from a master seed),
and :func:`map_tasks` returns results in task order whatever order they finish in.

On a 2-core machine a process pool with chunked tasks is the fastest; Ray is for
users who have a cluster (``backend="ray"``, ``ray_address="auto"`` or an address).

Clean ends (``local``): workers ignore Ctrl-C (the parent handles it) and run a watchdog
thread that ends the worker within :data:`PARENT_POLL_SECONDS` once the parent process is
gone (SIGKILL, SIGTERM, a crash), so no worker, forkserver or resource tracker is left
behind. When the consumer stops early (an exception, Ctrl-C, ``close()``), pending tasks
are cancelled and the workers are terminated instead of finishing their chunks.

Reusing workers: every :func:`map_tasks` / :func:`imap_tasks` call on its own starts a pool
(``local``: processes that import the library, several seconds each on a loaded machine) or a
Ray instance and stops it at the end. A job of many parallel stages opens one
:class:`TaskPool` instead::

    with TaskPool("local", workers=2) as pool:
        a = pool.map(f, items)          # explicit
        b = map_tasks(g, more)          # implicit: calls inside the block that ask for the
                                        # pool's backend (and its or no worker count) use it

Results are the same with or without a pool (each task's result depends only on its item).
"""

from __future__ import annotations

import contextvars
import logging
import os
import socket
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np

from riskplan._validation import check_workers, seed_sequence
from riskplan._workers import (
    PARENT_POLL_SECONDS,
    cpu_seconds,
    init_worker,
    pool_processes,
    run_chunk,
    terminate_pool,
)
from riskplan.errors import BackendUnavailableError, InvalidInputError, require

__all__ = [
    "PARENT_POLL_SECONDS",
    "RAY_CONNECT_TIMEOUT_S",
    "TaskPool",
    "active_pool",
    "check_ray_address",
    "chunk_count",
    "chunk_size",
    "default_workers",
    "effective_workers",
    "imap_tasks",
    "map_tasks",
    "parse_ray_address",
    "spawn_seeds",
]

log = logging.getLogger(__name__)

BACKENDS = ("serial", "local", "ray")
#: Seconds to wait for a Ray head to accept a TCP connection before giving up.
RAY_CONNECT_TIMEOUT_S = 5.0


def spawn_seeds(seed: int | None, n: int) -> list[int]:
    """``n`` independent 63-bit integer seeds derived from ``seed`` (NumPy ``SeedSequence.spawn``).

    A seed NumPy cannot use (a negative integer, a float, a string) raises
    :class:`~riskplan.errors.InvalidInputError` naming ``seed``.

    Parameters
    ----------
    seed : int or None
        The root seed.
    n : int
        Seeds to derive.

    Returns
    -------
    list of int
        ``n`` seeds in ``[0, 2^63)``.
    """
    ss = seed_sequence(seed)
    return [int(c.generate_state(2, dtype=np.uint64)[0] >> np.uint64(1)) for c in ss.spawn(n)]


def default_workers() -> int:
    """The cores this process may run on (its CPU affinity; the CPU count elsewhere).

    Returns
    -------
    int
        At least 1.
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


_CAPPED: set = set()


def effective_workers(backend: str, workers: int | None, ray_address: str | None = None) -> int:
    """The worker count a pool runs with: ``workers`` (``None``: one per core), capped at the
    cores available unless the work goes to a Ray cluster (``backend="ray"`` with an
    address), whose size this machine does not bound. More processes than cores only
    contend (20 processes on 2 cores ran a reproduction 10x slower); the cap is logged.

    Parameters
    ----------
    backend : str
        The backend the pool runs on.
    workers : int or None
        Requested workers.
    ray_address : str, optional
        A Ray cluster's address.

    Returns
    -------
    int
        The worker count.
    """
    n = int(workers or default_workers())
    cores = default_workers()
    if n > cores and not (backend == "ray" and ray_address):
        if (n, cores) in _CAPPED:
            return cores
        _CAPPED.add((n, cores))  # said once per process, not for every stage's pool
        log.warning(
            "workers: %d requested, %d cores available; using %d (more processes than cores only "
            "contend; a Ray cluster (--backend ray --address) is not capped)",
            n,
            cores,
            cores,
        )
        n = cores
    return n


def chunk_count(n_items: int, backend: str, workers: int | None, *, per_worker: int = 4) -> int:
    """How many interleaved chunks a map over ``n_items`` is cut into (the one rule).

    Parameters
    ----------
    n_items : int
        Number of items to map.
    backend : str
        ``"serial"`` runs everything as one chunk.
    workers : int or None
        As everywhere in riskplan: ``None`` is one per core, and the count is capped at the
        cores (:func:`effective_workers`).
    per_worker : int
        Chunks per worker (several keep the workers busy when chunks take unequal time).

    Returns
    -------
    int
        ``1`` for the serial backend or at most one item, else
        ``min(n_items, per_worker · effective_workers(backend, workers))``.
    """
    if backend == "serial" or n_items <= 1:
        return 1
    return max(1, min(int(n_items), per_worker * effective_workers(backend, workers)))


def chunk_size(n_items: int, backend: str, workers: int | None, *, most: int = 8) -> int:
    """Items per task for streaming maps (:func:`imap_tasks`): about four tasks per
    worker, at most ``most`` items each.

    Parameters
    ----------
    n_items : int
        Number of items to map.
    backend : str
        The backend the map runs on.
    workers : int or None
        ``None`` is one per core (:func:`effective_workers`).
    most : int
        Upper bound on the size (progress stays fine-grained).

    Returns
    -------
    int
        ``max(1, min(most, n_items // chunk_count(n_items, backend, workers)))``.
    """
    if n_items <= 0:
        return 1
    return max(1, min(most, n_items // chunk_count(n_items, backend, workers)))


#: The :class:`TaskPool` whose ``with`` block is running in this context (thread, task).
_ACTIVE_POOL: contextvars.ContextVar = contextvars.ContextVar("riskplan_task_pool", default=None)


class TaskPool:
    """Workers kept alive across many :func:`map_tasks` calls (a context manager).

    ``backend``: ``"serial"``, ``"local"`` or ``"ray"``; ``workers``: processes (``None``: one
    per core); ``ray_address``: as in :func:`imap_tasks`. ``local`` workers start on the
    first call that needs them and stay until :meth:`close` (the end of the ``with`` block);
    Ray is initialised once on entry (when not already) and shut down on exit. Inside the
    ``with`` block, :func:`imap_tasks` / :func:`map_tasks` calls of this thread that ask for
    the same backend with the same or no worker count (and no other Ray address) run on it.

    Clean ends as without a pool: worker initialiser and watchdog unchanged; when a call ends
    early (a task raised, Ctrl-C, the consumer closed the generator) the workers are
    terminated and the next call starts fresh ones. One call at a time per pool.

    ``workers_cpu_s``: the CPU seconds of the ``local`` workers, read from each worker just
    before it stops (so complete after the ``with`` block); ``None`` where they cannot be read.
    """

    def __init__(
        self, backend: str = "local", workers: int | None = None, ray_address: str | None = None
    ):
        if backend not in BACKENDS:
            raise InvalidInputError(f"backend: expected one of {BACKENDS}, got {backend!r}")
        check_workers(workers)
        self.backend = backend
        self.workers = effective_workers(backend, workers, ray_address)
        self._requested = None if workers is None else int(workers)
        self.ray_address = ray_address
        self.pools_started = 0  #: local process pools started so far (diagnostics)
        #: CPU seconds of the local workers stopped so far, read just before they stop (Linux;
        #: ``None`` where a worker's CPU time cannot be read, and with Ray; 0 when serial)
        self.workers_cpu_s: float | None = None if backend == "ray" else 0.0
        self._executor = None
        self._ray = None
        self._ray_started_here = False
        self._token = None
        self._closed = False

    # --- lifecycle ------------------------------------------------------------------------
    def __enter__(self) -> TaskPool:
        if self.backend == "ray":
            self._ensure_ray()
        self._token = _ACTIVE_POOL.set(self)
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._token is not None:
            _ACTIVE_POOL.reset(self._token)
            self._token = None
        if exc_type is not None:
            self._terminate()
        self.close()

    def close(self) -> None:
        """Stop the workers (waiting for them) and Ray if this pool started it."""
        self._closed = True
        if self._executor is not None:
            ex, self._executor = self._executor, None
            self._count_cpu(ex)
            ex.shutdown(wait=True)
        if self._ray_started_here:
            self._ray.shutdown()
            self._ray_started_here = False

    def _terminate(self) -> None:
        if self._executor is not None:
            ex, self._executor = self._executor, None
            self._count_cpu(ex)
            terminate_pool(ex)

    def _count_cpu(self, ex) -> None:
        """Add the CPU seconds of executor ``ex``'s workers to ``workers_cpu_s``."""
        for proc in pool_processes(ex):
            total, cpu = self.workers_cpu_s, cpu_seconds(proc.pid)
            self.workers_cpu_s = None if cpu is None or total is None else total + cpu

    def accepts(self, backend: str, workers: int | None, ray_address: str | None) -> bool:
        """Whether a call asking for ``backend`` / ``workers`` / ``ray_address`` can run here.

        Parameters
        ----------
        backend : str
            The backend asked for.
        workers : int or None
            The workers asked for (None: any).
        ray_address : str or None
            The Ray address asked for (None: any).

        Returns
        -------
        bool
            Whether the call can run on this pool.
        """
        return (
            not self._closed
            and backend == self.backend
            and (workers is None or int(workers) in (self.workers, self._requested))
            and (ray_address is None or ray_address == self.ray_address)
        )

    # --- backends -------------------------------------------------------------------------
    def _ensure_executor(self):
        if self._executor is None:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            # forkserver: safe with torch / OpenMP state in the parent, unlike fork.
            ctx = mp.get_context("forkserver")
            self._executor = ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=ctx,
                initializer=init_worker,
                initargs=(os.getpid(),),
            )
            self.pools_started += 1
        return self._executor

    def _ensure_ray(self):
        if self._ray is None:
            self._ray = require("ray", "ray")
        ray = self._ray
        if not ray.is_initialized():
            if self.ray_address:
                check_ray_address(self.ray_address)
            # "local": always a fresh local instance, never a cluster some `ray start` left behind.
            kwargs = (
                {"address": self.ray_address}
                if self.ray_address
                else {"address": "local", "num_cpus": self.workers}
            )
            try:
                ray.init(
                    ignore_reinit_error=True, log_to_driver=False, include_dashboard=False, **kwargs
                )
            except ConnectionError as exc:
                raise BackendUnavailableError(
                    f"ray_address={self.ray_address!r}: cannot connect to a Ray cluster ({exc})"
                ) from exc
            self._ray_started_here = True
        return ray

    # --- mapping --------------------------------------------------------------------------
    def imap(
        self, fn: Callable[[Any], Any], items: Iterable[Any], *, chunksize: int | None = None
    ) -> Iterator[tuple[int, Any]]:
        """Yield ``(index, fn(item))`` as tasks complete (see :func:`imap_tasks`).

        Parameters
        ----------
        fn, items, chunksize
            As :func:`imap_tasks`.

        Yields
        ------
        tuple
            ``(index, fn(items[index]))``.
        """
        if self._closed:
            raise InvalidInputError("TaskPool: used after close()")
        indexed = list(enumerate(items))
        if not indexed:
            return
        if chunksize is None:
            chunksize = max(1, len(indexed) // (4 * self.workers))
        chunks = [indexed[k : k + chunksize] for k in range(0, len(indexed), chunksize)]

        if self.backend == "serial" or (self.backend == "local" and self.workers == 1):
            for chunk in chunks:
                yield from run_chunk(fn, chunk)
            return

        if self.backend == "local":
            from concurrent.futures import FIRST_COMPLETED, wait

            pool = self._ensure_executor()
            try:
                pending = {pool.submit(run_chunk, fn, c) for c in chunks}
                while pending:
                    done, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for fut in done:
                        yield from fut.result()
            except BaseException:  # a task failed, Ctrl-C, or the consumer closed the generator
                self._terminate()
                raise
            return

        ray = self._ensure_ray()
        remote = ray.remote(run_chunk)
        refs = [remote.remote(fn, c) for c in chunks]
        while refs:
            done, refs = ray.wait(refs, num_returns=1)
            for ref in done:
                yield from ray.get(ref)

    def map(
        self,
        fn: Callable[[Any], Any],
        items: Iterable[Any],
        *,
        chunksize: int | None = None,
        on_result: Callable[[int, Any], None] | None = None,
    ) -> list[Any]:
        """``[fn(item) for item in items]`` in task order (see :func:`map_tasks`).

        Parameters
        ----------
        fn, items, chunksize, on_result
            As :func:`map_tasks`.

        Returns
        -------
        list
            The results in item order.
        """
        items = list(items)
        out: list[Any] = [None] * len(items)
        for i, r in self.imap(fn, items, chunksize=chunksize):
            out[i] = r
            if on_result is not None:
                on_result(i, r)
        return out


def active_pool() -> TaskPool | None:
    """The :class:`TaskPool` whose ``with`` block encloses this call, if any.

    Returns
    -------
    TaskPool or None
    """
    return _ACTIVE_POOL.get()


def imap_tasks(
    fn: Callable[[Any], Any],
    items: Iterable[Any],
    *,
    backend: str = "local",
    workers: int | None = None,
    chunksize: int | None = None,
    ray_address: str | None = None,
    pool: TaskPool | None = None,
) -> Iterator[tuple[int, Any]]:
    """Yield ``(index, fn(item))`` as tasks complete (order not guaranteed except for ``serial``).

    ``fn`` must be picklable (a module-level function or ``functools.partial`` of one)
    for the ``local`` and ``ray`` backends. Exceptions raised by a task propagate.

    ``pool``: run on this :class:`TaskPool` (``backend``, ``workers`` and ``ray_address`` are
    then the pool's). Without it, the enclosing ``with TaskPool(...)`` block's pool is used
    when it accepts the call (:meth:`TaskPool.accepts`), else a pool is started for this
    call and stopped at its end.

    Parameters
    ----------
    fn : callable
        The task, ``fn(item)``.
    items : iterable
        The items.
    backend : {"serial", "local", "ray"}
        Where the tasks run.
    workers : int or None
        Worker processes (:func:`effective_workers`).
    chunksize : int, optional
        Items per task (default: four tasks per worker).
    ray_address : str, optional
        A Ray cluster's address (``backend="ray"``).
    pool : TaskPool, optional
        The pool to run on.

    Yields
    ------
    tuple
        ``(index, fn(items[index]))``.
    """
    if backend not in BACKENDS:
        raise InvalidInputError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    check_workers(workers)
    if pool is None:
        active = _ACTIVE_POOL.get()
        if active is not None and active.accepts(backend, workers, ray_address):
            pool = active
    if pool is not None:
        yield from pool.imap(fn, items, chunksize=chunksize)
        return
    items = list(items)
    if not items:
        return
    # a pool for this call only (not made the active one: a generator runs in its consumer's
    # context); a Ray instance someone else started is used and left running
    own = TaskPool(backend, workers, ray_address)
    try:
        yield from own.imap(fn, items, chunksize=chunksize)
    finally:
        own.close()


def parse_ray_address(address: str) -> tuple[str, int] | None:
    """``(host, port)`` of a Ray address ``"host:port"`` or ``"ray://host:port"``; ``None`` for
    ``"auto"`` / ``"local"`` (Ray finds or starts the cluster itself).

    Parameters
    ----------
    address : str
        The address.

    Returns
    -------
    tuple or None
        ``(host, port)``.
    """
    if not isinstance(address, str) or not address.strip():
        raise InvalidInputError(
            f"ray_address: expected 'host:port', 'ray://host:port' or 'auto', got {address!r}"
        )
    address = address.strip()
    if address in ("auto", "local"):
        return None
    hostport = address.split("://", 1)[1] if "://" in address else address
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InvalidInputError(
            f"ray_address: expected 'host:port', 'ray://host:port' or 'auto', got {address!r}"
        )
    return host.strip("[]"), int(port)


def check_ray_address(address: str, timeout: float = RAY_CONNECT_TIMEOUT_S) -> None:
    """Fail fast when nothing listens at a Ray address: ``ray.init`` itself retries for minutes.

    Raises :class:`~riskplan.errors.BackendUnavailableError` within ``timeout`` seconds when the
    head's port does not accept a TCP connection.

    Parameters
    ----------
    address : str
        The address.
    timeout : float
        Seconds to wait for the connection.
    """
    hp = parse_ray_address(address)
    if hp is None:
        return
    try:
        socket.create_connection(hp, timeout=timeout).close()
    except OSError as exc:
        raise BackendUnavailableError(
            f"ray_address={address!r}: no Ray head answers at {hp[0]}:{hp[1]} ({exc.strerror or exc}); "
            "start one with `ray start --head --port PORT` or check the address"
        ) from exc


def map_tasks(
    fn: Callable[[Any], Any],
    items: Iterable[Any],
    *,
    backend: str = "local",
    workers: int | None = None,
    chunksize: int | None = None,
    ray_address: str | None = None,
    on_result: Callable[[int, Any], None] | None = None,
    pool: TaskPool | None = None,
) -> list[Any]:
    """``[fn(item) for item in items]`` on ``backend``, in task order.

    ``on_result(index, result)`` is called as each task completes (for progress
    bars or incremental saving). ``pool``: see :func:`imap_tasks`.

    Parameters
    ----------
    fn, items, backend, workers, chunksize, ray_address, pool
        As :func:`imap_tasks`.
    on_result : callable, optional
        ``on_result(index, result)``.

    Returns
    -------
    list
        The results in item order.
    """
    items = list(items)
    out: list[Any] = [None] * len(items)
    for i, r in imap_tasks(
        fn,
        items,
        backend=backend,
        workers=workers,
        chunksize=chunksize,
        ray_address=ray_address,
        pool=pool,
    ):
        out[i] = r
        if on_result is not None:
            on_result(i, r)
    return out
