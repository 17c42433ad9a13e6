"""Compiled kernels: warm numba's on-disk cache once, so that no command compiles.

riskplan's hot loops (the Cosserat solver in :mod:`riskplan.robots`, the collision kernels in
``riskplan.collision._kernels``, the planar predicates in :mod:`riskplan.geometry2d`, the
neo-Hookean FEM in :mod:`riskplan.deformable.nhkernels`) are
numba functions compiled with ``cache=True``: the first call in a fresh environment compiles
them (tens of seconds of CPU for the robot solver), later processes load machine code from the
cache beside each module (``__pycache__``, or ``NUMBA_CACHE_DIR`` when set).

:func:`warm` makes those first calls on small inputs, through the same public functions the
commands use, so every specialisation the commands need is compiled and cached.
``make install`` (and so ``make demo`` and ``make test``) runs it once, as ``riskplan warm``;
afterwards a fresh process reaches its first robot shape in about a second.
:func:`kernel_dispatchers` lists every kernel and :func:`cold` the ones with nothing cached yet (a test checks that :func:`warm` leaves none).

The module is part of the application layer (docs/architecture.md): it names, and imports
when called, the kernel modules of the core and of both wings.
"""

from __future__ import annotations

import importlib
import os
import time
from collections.abc import Callable

import numpy as np

__all__ = ["KERNEL_MODULES", "cold", "kernel_dispatchers", "warm"]

#: the modules that define numba kernels (``@njit(cache=True)``)
KERNEL_MODULES = (
    "riskplan.robots.linalg6",
    "riskplan.robots.rod_tables",
    "riskplan.robots.strains",
    "riskplan.robots.tendon_lengths",
    "riskplan.robots.integration",
    "riskplan.robots.displacement",
    "riskplan.robots.robot",
    "riskplan.robots.batch_kernel",
    "riskplan.collision._kernels",
    "riskplan.geometry2d",
    "riskplan._triangles",
    "riskplan.deformable.nhkernels",
    "riskplan.deformable.tetfactor",
    "riskplan.deformable.tetlocate",
    "riskplan.scenarios.tissue3d",
    "riskplan.scenarios.bevel",
)


def kernel_dispatchers() -> dict[str, object]:
    """``{"module.function": dispatcher}`` for every numba kernel in :data:`KERNEL_MODULES`
    (imports them).

    Returns
    -------
    dict
        Dotted name to numba dispatcher.
    """
    from numba.core.registry import CPUDispatcher

    out = {}
    for name in KERNEL_MODULES:
        mod = importlib.import_module(name)
        for attr, obj in vars(mod).items():
            if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == name:
                out[f"{name}.{attr}"] = obj
    return out


def cold() -> list[str]:
    """Kernels with nothing in numba's cache yet (no index file where this process looks),
    except those numba inlines into their callers (``inline="always"``: never cached alone).

    Returns
    -------
    list of str
        Sorted dotted names.
    """
    return sorted(
        name
        for name, d in kernel_dispatchers().items()
        if d.targetoptions.get("inline") != "always"
        and not os.path.exists(d._cache._cache_file._index_path)
    )


def _robot() -> None:
    from riskplan.robots import load_robot
    from riskplan.robots.actuation import BATCH_KERNEL_MIN
    from riskplan.robots.batch_kernel import solve_tensions_batch

    robot = load_robot("paper")
    tau = np.linspace(0.0, 1.0, BATCH_KERNEL_MIN * robot.n_tendons).reshape(BATCH_KERNEL_MIN, -1)
    robot.solve_tensions(tau[1])  # one configuration: the scalar kernel
    robot.solve_tensions(tau[:2])  # a small batch: the per-configuration loop
    robot.solve_tensions(tau)  # the SIMD batch kernel, serial
    solve_tensions_batch(robot, tau, parallel=True)  # and its threaded variant
    robot.with_gravity(True).solve_tensions(tau[1])  # shooting under external load
    d = np.zeros((2, robot.n_tendons))
    d[1, 0] = 0.01
    robot.solve_displacements(d[1])
    robot.solve_displacements(d)
    # the compiled tendon offsets at one arc length (robots build their tables with numpy,
    # the same operations; the kernel stays public and is the tests' reference)
    from riskplan.robots.rod_tables import tendon_offsets

    coeffs = np.ones((robot.n_tendons, 2))
    rt, drt = np.empty((robot.n_tendons, 3)), np.empty((robot.n_tendons, 3))
    tendon_offsets(coeffs, coeffs, 0.5, rt, drt)


def _collision() -> None:
    from riskplan.collision import Environment, probability_of_collision
    from riskplan.collision._kernels import closest_points_brute
    from riskplan.gaussian_mixture import NumpyMixture

    # a unit cube as two obstacles' worth of triangles is enough to compile every kernel
    v = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    f = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    )  # fmt: skip
    env = Environment(v, f)
    gm = NumpyMixture.from_covariances([1.0], [[0.5, 0.5, 2.0]], [np.eye(3) * 0.04])
    probability_of_collision(gm, env)
    pts = np.array([[0.5, 0.5, 0.5], [2.0, 2.0, 2.0]])
    env.contains(pts)
    env.closest_points(pts)
    env.segments_collide(pts[:1], pts[1:])
    closest_points_brute(v, f, pts)


def _geometry2d() -> None:
    from riskplan import geometry2d as geo

    sq = geo.rectangle_polygon([0.0, 0.0], [1.0, 1.0])
    other = geo.rectangle_polygon([0.5, 0.5], [2.0, 2.0])
    pts = np.array([[0.5, 0.5], [3.0, 3.0]])
    geo.points_in_polygon(pts, sq)
    geo.winding_numbers(geo.polygon_segments(sq), pts)
    geo.segments_intersect(pts[:1], pts[1:], sq[:1], sq[2:3])
    geo.segments_hit(geo.polygon_segments(sq), pts[:1], pts[1:])
    geo.polygons_intersect(sq, other)
    geo.check_simple_polygon(sq, "warm")
    geo.point_polygon_distance(pts, sq)
    nodes = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    tris = np.array([[0, 1, 2], [1, 3, 2]])
    grid = geo.TriangleLocator(nodes, tris)
    grid.locate(pts[0])
    grid.locate_points(pts)
    # and on read-only maps, as a tissue mesh's locator gets them (its cached maps are frozen):
    # numba compiles a signature of its own for read-only arrays
    maps = geo.barycentric_maps(nodes, tris)
    maps.flags.writeable = False
    grid = geo.TriangleLocator(nodes, tris, maps=maps)
    grid.locate(pts[0])
    grid.locate_points(pts)


def _deformable() -> None:
    # one P1 triangle with two nodes held (the tissue wing's kernels)
    from riskplan.deformable import nhkernels as k

    tri = np.array([[0, 1, 2]], dtype=np.int64)
    G = np.array([[[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]]])
    areas = np.array([0.5])
    u = np.zeros(6)
    Finv, lnJ, J = np.empty((1, 2, 2)), np.empty(1), np.empty(1)
    k.neohookean_evaluate(u, tri, G, areas, 1.0, 1.0, np.empty(6), Finv, lnJ, J)
    slot = np.full((1, 36), -1, dtype=np.int64)
    slot[0, 0] = 0
    R = np.empty(1)
    k.neohookean_band(Finv, lnJ, G, areas, 1.0, 1.0, slot, R)
    R = R.reshape(1, 1)
    k.band_cholesky(R)
    k.band_cholesky_solve(R, np.zeros(1, dtype=np.int64), np.ones(1))
    k.scaled_norm(np.ones(1))


def _tissue3d() -> None:
    # the 3-D needle's kernels (tissue wing), on minimal inputs of the types their callers
    # pass: the band of a 3x3 SPD matrix's factor as scipy returns it, one grid cell with one
    # tetrahedron, one element's point load, one pose-vector step
    import scipy.linalg

    from riskplan.deformable import tetfactor, tetlocate
    from riskplan.scenarios import bevel, tissue3d

    ab = np.array([[0.0, -1.0, -1.0], [4.0, 4.0, 4.0]])
    tetfactor.band_inverse(scipy.linalg.cholesky_banded(ab, lower=False))
    one = np.ones(3)
    cell_tets = np.zeros((1, 1), dtype=np.int64)
    maps = np.zeros((1, 1, 4, 4))
    grid = np.ones(3, dtype=np.int64)
    edofs = np.arange(12, dtype=np.int64).reshape(1, 12)
    G, W = np.zeros((1, 12, 12)), np.zeros((12, 3))
    G.flags.writeable = False  # the model's cached Green's functions are read-only
    tissue3d._point_load_kernel(G, W, edofs, 0, np.full(4, 0.25), one)
    pose = np.concatenate([np.zeros(3), np.eye(3).reshape(-1)])
    X = 0.5 * one
    for _ in range(2):  # writeable, then read-only (a state's arrays are frozen): two signatures
        tetlocate.locate_in_grid(X, one, grid, cell_tets, maps, tetlocate.INSIDE_TOL)
        bevel._pose_vector_step(pose, 1.0, 0.0, 0.1, 1.0, 0.5)
        X.flags.writeable = pose.flags.writeable = False


#: (area, function) in the order :func:`warm` runs them
AREAS: tuple[tuple[str, Callable[[], None]], ...] = (
    ("robot", _robot),
    ("collision", _collision),
    ("geometry2d", _geometry2d),
    ("deformable", _deformable),
    ("tissue3d", _tissue3d),
)


def _timed(area: str) -> float:
    """Run one area's warm-up (in a worker process of :func:`warm`); its wall time."""
    fn = dict(AREAS)[area]
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def warm(
    progress: Callable[[str], None] | None = None,
    workers: int = 1,
    areas: tuple[str, ...] | None = None,
) -> dict[str, float]:
    """Compile (or load from the cache) every kernel the commands use.

    Parameters
    ----------
    progress : callable, optional
        Called with each area's name before it runs (``"robot"``, ``"collision"``,
        ``"geometry2d"``, ``"deformable"``, ``"tissue3d"``).
    workers : int
        Processes that compile at once (``1``: in this process, one area after the other).
        The areas compile disjoint modules' kernels and numba writes each kernel's cache
        entry by itself, so with ``workers > 1`` the areas compile in a process pool (the
        robot area, about two thirds of the compile time, beside the others); this process
        then loads them from the cache when it calls them.
    areas : tuple of str, optional
        The areas to warm (names in ``AREAS``); all by default.

    Returns
    -------
    dict
        Wall time in seconds per area: compile time on a cold cache, load time on a warm one.
    """
    from riskplan._validation import check_count
    from riskplan.errors import InvalidInputError

    check_count(workers, "workers", 1, integral=True)
    names = [a for a, _ in AREAS]
    chosen = names if areas is None else list(areas)
    unknown = sorted(set(chosen) - set(names))
    if unknown:
        raise InvalidInputError(f"areas: unknown {unknown}; expected some of {names}")
    if workers == 1:
        times = {}
        for area in chosen:
            if progress is not None:
                progress(area)
            times[area] = _timed(area)
        return times
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # spawn: a clean interpreter per worker (no forked numba or thread state)
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=int(workers), mp_context=ctx) as pool:
        futures = {}
        for area in chosen:
            if progress is not None:
                progress(area)
            futures[area] = pool.submit(_timed, area)
        return {area: f.result() for area, f in futures.items()}
