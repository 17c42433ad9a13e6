"""BLAS thread limits for the numeric hot paths.

The FEM factorisations (dense Cholesky inverse, LAPACK banded Cholesky) are small: on a
few cores, OpenBLAS's worker threads cost more than they save (a 2,000-element
:class:`~riskplan.deformable.LinearElasticModel` builds 4-10x slower with the default
threads than with one on 2 busy cores; see docs/architecture.md, "Threads"). The CLI and
the worker processes already set one thread per process through the environment; this
module gives library users the same speed from plain Python: the FEM models run their
factorisations and Newton solves inside :func:`blas_threads`, which lowers the BLAS pools
to ``limit`` threads for the duration of the call and restores the caller's settings
afterwards. When the pools already use no more threads, it changes nothing.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

__all__ = [
    "THREAD_ENV",
    "blas_pools",
    "blas_threads",
    "limit_process_threads",
    "one_blas_thread",
    "one_torch_thread",
    "torch_threads",
]

F = TypeVar("F", bound=Callable)

_blas_pools: list | None = None


def blas_pools() -> list:
    """``threadpoolctl`` controllers of the BLAS libraries loaded by NumPy and SciPy
    (looked up once per process; SciPy is imported first so its own OpenBLAS is seen).

    Returns
    -------
    list
        ``threadpoolctl`` library controllers.
    """
    global _blas_pools
    if _blas_pools is None:
        import scipy.linalg  # noqa: F401 - loads SciPy's BLAS before the lookup
        from threadpoolctl import ThreadpoolController

        _blas_pools = [lc for lc in ThreadpoolController().lib_controllers if lc.user_api == "blas"]
    return _blas_pools


@contextmanager
def blas_threads(limit: int = 1) -> Iterator[None]:
    """Run the block with at most ``limit`` BLAS threads per library, then restore the
    previous counts (only pools above ``limit`` are touched; ~10 us when none is).

    Parameters
    ----------
    limit : int
        Most BLAS threads per library inside the block.

    Yields
    ------
    None
    """
    changed = []
    for pool in blas_pools():
        n = pool.get_num_threads()
        if n is not None and n > limit:
            pool.set_num_threads(limit)
            changed.append((pool, n))
    try:
        yield
    finally:
        for pool, n in reversed(changed):
            pool.set_num_threads(n)


def one_blas_thread(fn: F) -> F:
    """Decorator: run ``fn`` inside ``blas_threads(1)``.

    Parameters
    ----------
    fn : callable
        The function to wrap.

    Returns
    -------
    callable
        The wrapper.
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with blas_threads(1):
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


#: The environment variables that cap the OpenMP/BLAS pools of a process at start-up.
THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def limit_process_threads(n: int = 1) -> None:
    """The thread policy of a process riskplan owns (the CLI, a worker process).

    Parameters
    ----------
    n : int
        Threads per pool. Variables of :data:`THREAD_ENV` the user set are kept (an
        explicit choice wins); torch, which reads ``OMP_NUM_THREADS`` when it is first
        imported, follows them, and a torch imported already is set to ``n`` too.

    Notes
    -----
    Library code never calls this (it changes the process); it uses :func:`torch_threads`
    or :func:`blas_threads`, which restore what they change.
    """
    import os
    import sys

    for var in THREAD_ENV:
        os.environ.setdefault(var, str(int(n)))
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", n)))


@contextmanager
def torch_threads(limit: int = 1) -> Iterator[None]:
    """Run the block with at most ``limit`` torch intra-op threads, then restore the count.

    Parameters
    ----------
    limit : int
        Upper bound on ``torch.get_num_threads()`` inside the block.

    Yields
    ------
    None
        Small MDN batches on few shared cores run faster on one thread; the caller's
        setting is back after the block, whatever it raised.
    """
    import torch

    before = torch.get_num_threads()
    if before > limit:
        torch.set_num_threads(limit)
    try:
        yield
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)


def one_torch_thread(fn: F) -> F:
    """Decorator: run ``fn`` inside ``torch_threads(1)``.

    Parameters
    ----------
    fn : callable
        The function to wrap.

    Returns
    -------
    callable
        ``fn`` with at most one torch thread for the duration of each call.
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with torch_threads(1):
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
