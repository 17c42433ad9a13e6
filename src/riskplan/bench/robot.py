"""``riskplan bench robot``: Cosserat-model speed.

Figures (median wall time, paper robot, no gravity, 5 mm step):

* ``tension_single_ms`` — ``robot.solve_tensions`` for one configuration (validation included).
* ``tension_kernel_single_us`` — the compiled kernel behind it (``cosserat.shape_free``, outputs
  preallocated), so that the difference is the facade's cost (checks, allocation, ``RodShape``).
* ``tension_batched_us_per_config`` — one ``solve_tensions`` call on 10,000 configurations.
* ``displacement_single_ms`` — ``robot.solve_displacements`` for one configuration.
* ``dataset_small_s`` — wall time of generating the ``small`` preset (train and test splits,
  ``riskplan.datasets.generate_splits``), serial backend (None with ``include_dataset=False``).
* ``first_call_cold_s`` — a fresh Python process, from its start to its first
  ``solve_displacements``, with an empty numba cache (``NUMBA_CACHE_DIR`` set to a new folder):
  what the first command costs when nothing is compiled (None with ``include_first_call=False``);
  ``first_call_cold_cpu_s``: its CPU time (user + system; on a shared machine the wall time
  also counts the waits for a core).
* ``first_call_installed_s`` — the same process with the package's own kernel cache, as
  ``make install`` leaves it (it runs ``riskplan warm``), and ``first_call_installed_cpu_s``
  its CPU time; ``kernel_cache_complete`` says
  whether every kernel was cached when it was measured (:func:`riskplan.kernels.cold`).

Anchors: the compiled C++ peer (Kuntz-Lab/interactive-rate-tendons) takes 66-73 us per
configuration on a 2-core machine; the MDN paper quotes 0.39 ms for its Cosserat model.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from riskplan.errors import InvalidInputError

N_BATCH = 10_000


def _dataset_small_s() -> float:
    """Wall time of generating the small data set (train and test splits, serial backend)."""
    from riskplan.datasets import generate_splits
    from riskplan.robots import load_robot

    robot = load_robot("paper")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        generate_splits(robot, "small", Path(tmp) / "small", seed=0, workers=1, backend="serial")
        return time.perf_counter() - t0


_FIRST_CALL = (
    "from riskplan.robots import load_robot; "
    "load_robot('paper').solve_displacements([0.01, 0.0, 0.0, 0.0])"
)


def _first_call_s(cache_dir: str | None) -> tuple[float, float]:
    """Wall time and CPU time (user + system) of a fresh process that imports riskplan and
    solves one shape."""
    env = dict(os.environ)
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", _FIRST_CALL], env=env, check=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def first_call_figures(cold_cache_dir=None) -> dict:
    """The first-call figures, each from a fresh process that imports riskplan and solves one
    shape.

    Parameters
    ----------
    cold_cache_dir : str or path, optional
        An empty folder for the cold run's numba cache (``NUMBA_CACHE_DIR``), kept afterwards
        with what the run compiled into it; default a temporary folder, removed.

    Returns
    -------
    dict
        ``first_call_cold_s``, ``first_call_installed_s`` (wall, s), their CPU times
        ``first_call_cold_cpu_s``, ``first_call_installed_cpu_s`` (user + system, s) and
        ``kernel_cache_complete`` (bool, :func:`riskplan.kernels.cold` empty before the runs).

    Raises
    ------
    InvalidInputError
        ``cold_cache_dir`` is not an empty folder (the run would not be cold).
    """
    from riskplan.kernels import cold

    if cold_cache_dir is not None:
        folder = Path(cold_cache_dir)
        if not folder.is_dir() or any(folder.iterdir()):
            raise InvalidInputError(
                f"cold_cache_dir: expected an empty folder, got {str(folder)!r}"
            )
    complete = not cold()
    installed, installed_cpu = _first_call_s(None)
    if cold_cache_dir is not None:
        cold_s, cold_cpu = _first_call_s(str(cold_cache_dir))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            cold_s, cold_cpu = _first_call_s(tmp)
    return {
        "first_call_cold_s": cold_s,
        "first_call_cold_cpu_s": cold_cpu,
        "first_call_installed_s": installed,
        "first_call_installed_cpu_s": installed_cpu,
        "kernel_cache_complete": complete,
    }


def run(
    quick: bool = False, *, include_dataset: bool = True, include_first_call: bool = True
) -> dict:
    from riskplan.bench import median_time
    from riskplan.robots import cosserat, load_robot
    from riskplan.robots.rod_tables import LOCAL_MAXIT, LOCAL_TOL

    robot = load_robot("paper")
    rng = np.random.default_rng(0)
    lim = robot.tension_limits
    singles = rng.uniform(0.0, 1.0, (64, robot.n_tendons)) * lim * 0.5
    it = iter(range(10**9))
    t_single = median_time(
        lambda: robot.solve_tensions(singles[next(it) % 64]), repeats=50 if quick else 300, warmup=5
    )
    n = robot.n_stations
    P, Rs, X, lengths = (
        np.empty((n, 3)),
        np.empty((n, 3, 3)),
        np.empty((n, 6)),
        np.empty(robot.n_tendons),
    )
    kernel_args = (*robot.tables, LOCAL_TOL, LOCAL_MAXIT, P, Rs, X, lengths)
    t_kernel = median_time(
        lambda: cosserat.shape_free(singles[next(it) % 64], *kernel_args),
        repeats=50 if quick else 300,
        warmup=5,
    )
    n_batch = 1000 if quick else N_BATCH
    batch = rng.uniform(0.0, 1.0, (n_batch, robot.n_tendons)) * lim * 0.5
    t_batch = median_time(lambda: robot.solve_tensions(batch), repeats=3 if quick else 5, warmup=1)
    dl = robot.displacement_limits
    dsingles = rng.uniform(dl[:, 0], 0.5 * dl[:, 1], (64, robot.n_tendons))
    t_disp = median_time(
        lambda: robot.solve_displacements(dsingles[next(it) % 64]),
        repeats=30 if quick else 200,
        warmup=3,
    )
    out = {
        "tension_single_ms": t_single * 1e3,
        "tension_kernel_single_us": t_kernel * 1e6,
        "tension_batched_us_per_config": t_batch / n_batch * 1e6,
        "displacement_single_ms": t_disp * 1e3,
        "dataset_small_s": None,
    }
    if include_dataset:
        out["dataset_small_s"] = _dataset_small_s()
    out |= dict.fromkeys(
        (
            "first_call_cold_s",
            "first_call_cold_cpu_s",
            "first_call_installed_s",
            "first_call_installed_cpu_s",
            "kernel_cache_complete",
        )
    )
    if include_first_call:
        out |= first_call_figures()
    return out
