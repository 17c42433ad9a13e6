"""Generate point-cloud data sets by the MDN paper's protocol (section III); resumable.

One task per target configuration: for each of its ``S`` starts, a random start within the
limits, the straight path start -> target through the hysteresis model, the Cosserat shape
on arrival, the body surface and the two cameras' merged cloud, downsampled to ``P`` points.

Randomness: target ``i`` of a split gets its own seed ``spawn_seeds([seed, k], C)[i]``
(``k`` = 0 for train, 1 for test); inside a
task, start ``j`` gets child ``j`` of that seed and splits it into the start draw, the
per-run hysteresis variation and the camera noise. A configuration's data therefore depend
only on (robot, protocol, split, seed, i): the same on the serial, local and Ray backends,
and the same whether a generation ran in one go or was killed and resumed.

:func:`generate_dataset` checks its arguments and hands them unchanged to
``_generate_locked``, the part that runs while the output file's lock is held; the two
parameter lists match on purpose (a forwarding, not repeated logic).
"""

from __future__ import annotations

import functools
import logging
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from riskplan._validation import as_array, check_count, check_range, check_workers
from riskplan.datasets import storage
from riskplan.datasets.protocol import (
    SPLITS,
    Protocol,
    _check_split,
    exposure_upper,
    protocol_for_robot,
    protocol_limits,
    random_starts,
    scale_by_exposure,
    straight_path,
    target_configurations,
)
from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.parallel import BACKENDS, chunk_size, imap_tasks, spawn_seeds

log = logging.getLogger(__name__)


def _robot_from_toml(text: str):
    from riskplan.robots import cached_robot

    return cached_robot(text)


@functools.lru_cache(maxsize=4)
def _protocol_from_json(text: str) -> Protocol:
    return Protocol.from_json(text)


@functools.lru_cache(maxsize=8)
def _body(robot_toml: str, spacing: float):
    from riskplan.robots.geometry import BodyGeometry

    return BodyGeometry.from_params(_robot_from_toml(robot_toml).params, spacing=spacing)


def to_base_frame(robot, positions, rotations):
    """Backbone frames from the world frame to the robot's base frame: ``x_b = R_b^T (x_w - p_b)``."""
    base = robot.params.base
    Rb = np.asarray(base.rotation, dtype=np.float64)
    pb = np.asarray(base.position, dtype=np.float64)
    return (positions - pb) @ Rb, np.einsum("ji,...jk->...ik", Rb, rotations)


def arrive(robot, paths, seeds, upper=None):
    """Shapes on arrival after following commanded ``paths (S, T, n_config)`` through the
    hysteresis model.

    Each path starts at rest at its first point (no lag; :meth:`HysteresisModel.initial_state`)
    and draws its own run-to-run variation (play widths, zero offsets) from its entry of
    ``seeds`` (one ``SeedSequence`` per path). The tendon columns go through the play
    operator; base rotation and retraction (robots that have them) arrive as commanded: they
    are driven by a stage, not through the tendons' friction. Returns the effective
    configurations ``(S, n_config)`` and the :class:`~riskplan.robots.RodShape` batch ``(S,)``
    (world frame). ``upper (m,)``: a cap on the effective tendon displacements
    (:func:`~riskplan.datasets.protocol.exposure_upper`).
    """
    from riskplan.robots.hysteresis import HysteresisModel

    m = robot.n_tendons
    model = HysteresisModel(robot)
    eff = np.stack(
        [
            model.move(model.initial_state(p[0, :m]), p[:, :m], np.random.default_rng(sd))[1]
            for p, sd in zip(paths, seeds)
        ]
    )
    if upper is not None:
        eff = np.minimum(eff, upper)
    if robot.n_config == m:
        return eff, robot.solve_displacements(eff)
    _, rot, ret = robot.split_configuration(paths[:, -1, :], validate=False)
    shape = robot.solve_displacements(eff, rotation=rot, retraction=ret)
    return np.concatenate([eff, paths[:, -1, m:]], axis=1), shape


def simulate_target(
    robot,
    protocol: Protocol,
    target,
    seed,
    *,
    robot_toml: str | None = None,
    return_shapes: bool = False,
):
    """The ``S`` clouds of one target configuration (MDN paper section III).

    From each of ``S`` random starts the robot moves along a straight path to the target
    (hysteresis acting on the way); the arrival shape is sampled on its surface and seen by the
    protocol's cameras with noise.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    protocol : Protocol
        Starts, points, path steps, cameras, surface spacing.
    target : array_like, (n_config,)
        Target configuration (tendon displacements [m], then rotation [rad] and retraction [m]
        where the robot has them), within the protocol's limits.
    seed : int or numpy.random.SeedSequence
        Seed of this target.
    robot_toml : str, optional
        The robot's TOML text; when given, the body surface geometry is built from it through
        a per-process cache (workers reuse it across targets).
    return_shapes : bool
        Also return the arrival shapes.

    Returns
    -------
    dict
        ``points (S, P, 3) float32`` (base frame, m), ``tips (S, 3)``, ``starts (S, n_config)``,
        ``tensions (S, m)`` (N, on arrival) and, with ``return_shapes``, the arrival ``shape``
        (a batch of rod shapes, base frame).
    """
    from riskplan.robots.cameras import capture
    from riskplan.robots.geometry import BodyGeometry, sample_surface

    S = protocol.n_starts
    lim = protocol_limits(protocol, robot)
    target = as_array(target, "target", shape=(robot.n_config,))
    check_range(target, "target", low=lim[:, 0], high=lim[:, 1])
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    per_start = [c.spawn(3) for c in ss.spawn(S)]  # (start draw, hysteresis, camera) per start
    starts = np.stack([random_starts(lim, 1, np.random.default_rng(c[0]))[0] for c in per_start])
    if protocol.scale_by_exposure:
        starts = scale_by_exposure(starts, robot, lim)
    paths = np.stack([straight_path(st, target, protocol.path_steps) for st in starts])
    upper = None
    if protocol.scale_by_exposure and robot.base_motion.retraction:
        upper = exposure_upper(robot, float(target[-1]), lim)
    _, shape = arrive(robot, paths, [c[1] for c in per_start], upper)
    P, R = to_base_frame(robot, shape.positions, shape.rotations)
    if shape.s.ndim > 1:  # per-start retraction: each arrival has its own stations and body
        return _finish_retracted(
            robot, protocol, shape, P, R, starts, per_start, return_shapes, paths[:, -1, -1]
        )
    if robot_toml is not None:
        body = _body(robot_toml, protocol.surface_spacing)
    else:
        body = BodyGeometry.from_params(robot.params, spacing=protocol.surface_spacing)
    surf_p, surf_n = sample_surface(shape.s, P, R, body)
    cams = protocol.camera_objects()
    clouds = np.stack(
        [
            capture(surf_p[j], surf_n[j], cams, protocol.n_points, seed=per_start[j][2])
            for j in range(S)
        ]
    )
    out = {
        "points": clouds.astype(np.float32),
        "tips": P[:, -1, :].copy(),
        "starts": starts,
        "tensions": np.asarray(shape.tensions, dtype=np.float64),
    }
    if return_shapes:
        from riskplan.robots import RodShape

        out["shape"] = RodShape(shape.s, P, R, shape.tensions)
    return out


def _finish_retracted(robot, protocol, shape, P, R, starts, per_start, return_shapes, retractions):
    """:func:`simulate_target`'s clouds when the arrivals differ in retraction (exposed length):
    one body surface per arrival (the disks still exposed), rendered one by one."""
    from riskplan.robots.cameras import capture
    from riskplan.robots.geometry import BodyGeometry, sample_surface

    cams = protocol.camera_objects()
    clouds = []
    for j in range(len(starts)):
        body = BodyGeometry.from_params(
            robot.retracted(float(retractions[j])).params, spacing=protocol.surface_spacing
        )
        sp, sn = sample_surface(shape.s[j], P[j], R[j], body)
        clouds.append(capture(sp, sn, cams, protocol.n_points, seed=per_start[j][2]))
    out = {
        "points": np.stack(clouds).astype(np.float32),
        "tips": P[:, -1, :].copy(),
        "starts": starts,
        "tensions": np.asarray(shape.tensions, dtype=np.float64),
    }
    if return_shapes:
        from riskplan.robots import RodShape

        out["shape"] = RodShape(shape.s, P, R, shape.tensions)
    return out


def _task(item):
    robot_toml, protocol_json, target, seed = item
    robot = _robot_from_toml(robot_toml)
    protocol = _protocol_from_json(protocol_json)
    # Corners of the displacement box need more than max_tension: the solver warns once per
    # call, which would flood a long generation; the tensions are stored for diagnosis instead.
    rlog = logging.getLogger("riskplan.robots.robot")
    level = rlog.level
    rlog.setLevel(logging.ERROR)
    try:
        r = simulate_target(robot, protocol, target, seed, robot_toml=robot_toml)
    finally:
        rlog.setLevel(level)
    return r["points"], r["tips"], r["starts"], r["tensions"]


def _same(f, path, *, robot_toml, protocol_json, split, seed, displacements) -> None:
    meta = storage.check_header(f, path)
    problems = []
    if meta["robot_toml"] != robot_toml:
        problems.append("robot")
    if storage._attr(f, "protocol") != protocol_json:
        problems.append("protocol")
    if meta.get("split") != split:
        problems.append(f"split ({meta.get('split')!r} vs {split!r})")
    if int(meta["seed"]) != int(seed):
        problems.append(f"seed ({meta['seed']} vs {seed})")
    if f["displacements"].shape != displacements.shape or not np.array_equal(
        f["displacements"][...], displacements
    ):
        problems.append("target configurations")
    if problems:
        raise DataFormatError(
            f"{str(path)!r} was generated with a different {', '.join(problems)}; "
            "choose another output or pass overwrite=True (--overwrite)"
        )


def generate_dataset(
    robot,
    preset="small",
    out="data.h5",
    *,
    split: str = "train",
    seed: int = 0,
    workers: int | None = None,
    backend: str = "local",
    ray_address: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    overwrite: bool = False,
    max_new: int | None = None,
    chunksize: int | None = None,
    min_parallel_clouds: int = 400,
) -> Path:
    """Generate (or resume) one split of a data set into the HDF5 file ``out``.

    Resuming needs the same robot, protocol, split and seed, else :class:`DataFormatError`.

    Parameters
    ----------
    robot : TendonRobot or str or path
        A :class:`~riskplan.robots.TendonRobot` or a robot name/path for ``load_robot``.
    preset : str or Protocol
        Preset name (``"paper"``, ``"small"``, ``"tiny"``; adapted to the robot by
        :func:`~riskplan.datasets.protocol.protocol_for_robot`), a :class:`Protocol` or its JSON
        (taken as given).
    out : str or path
        Output file. Work in progress lives in ``<out>.partial`` and is renamed onto ``out``
        when every configuration is done.
    split : str
        ``"train"`` or ``"test"`` (disjoint sets of targets of the same protocol).
    seed : int
        Master seed of the starts, hysteresis variation and camera noise.
    workers, backend, ray_address
        Parallel map (:func:`riskplan.parallel.imap_tasks`).
    progress : callable, optional
        ``progress(done, total)`` after each finished configuration.
    overwrite : bool
        Replace an existing ``out`` / ``<out>.partial`` made with other settings.
    max_new : int, optional
        Compute at most this many configurations in this call and leave the rest for a
        later call (time-boxing; a call without it resumes and finishes).
    chunksize : int, optional
        Configurations per task of the parallel map (default: decided by
        :mod:`riskplan.parallel`).
    min_parallel_clouds : int
        With ``backend="local"``, less work than this many clouds runs in this process:
        starting a worker pool (process start, imports, compiled kernels) costs several seconds,
        more than a few hundred clouds take. The data are the same either way.

    Returns
    -------
    pathlib.Path
        The finished file, or the partial file if ``max_new`` stopped early.
    """
    from riskplan.robots import load_robot

    robot = load_robot(robot)
    protocol = protocol_for_robot(preset, robot)
    split = _check_split(split)
    if backend not in BACKENDS:
        raise InvalidInputError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    check_count(seed, "seed", 0)
    if max_new is not None and max_new < 0:
        raise InvalidInputError(f"max_new: expected >= 0, got {max_new}")
    check_workers(workers)
    out = Path(out)
    if out.is_dir():
        raise InvalidInputError(
            f"out: {str(out)!r} is a folder; expected a data-set file name (.h5)"
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    from riskplan.io import output_lock

    with output_lock(out, "data set"):
        return _generate_locked(
            robot,
            protocol,
            out,
            split,
            seed,
            workers,
            backend,
            ray_address,
            progress,
            overwrite,
            max_new,
            chunksize,
            min_parallel_clouds,
        )


def _generate_locked(
    robot,
    protocol,
    out,
    split,
    seed,
    workers,
    backend,
    ray_address,
    progress,
    overwrite,
    max_new,
    chunksize,
    min_parallel_clouds,
) -> Path:
    part = storage.partial_path(out)
    robot_toml = robot.toml_text()
    protocol_json = protocol.to_json()
    lim = protocol_limits(protocol, robot)
    targets = target_configurations(protocol, lim, split)
    if protocol.scale_by_exposure:
        targets = scale_by_exposure(targets, robot, lim)
    C = len(targets)
    if C == 0:
        raise InvalidInputError(f"protocol: split {split!r} has no configurations")
    settings = dict(
        robot_toml=robot_toml,
        protocol_json=protocol_json,
        split=split,
        seed=seed,
        displacements=targets,
    )

    import h5py

    if out.exists():
        # with overwrite the finished file stays until the new one is complete (os.replace below):
        # killing the new run loses nothing
        if not overwrite:
            try:
                with h5py.File(out, "r") as f:
                    _same(f, out, **settings)
                    complete = bool(storage._attr(f, "complete")) and bool(np.all(f["done"][...]))
            except OSError as exc:
                raise DataFormatError(
                    f"{str(out)!r} exists and is not a readable HDF5 file ({exc})"
                ) from exc
            if complete:
                log.info("%s is already complete", out)
                if progress is not None:
                    progress(C, C)
                return out
            raise DataFormatError(
                f"{str(out)!r} exists but is incomplete; pass overwrite=True (--overwrite)"
            )
    if part.exists() and overwrite:
        part.unlink()
    if part.exists():
        f = storage.open_existing(part)
        try:
            _same(f, part, **settings)
        except BaseException:
            f.close()
            raise
        log.info("resuming %s: %d of %d configurations done", part, int(f["done"][...].sum()), C)
    else:
        f = storage.create_file(
            part,
            displacements=targets,
            n_tendons=robot.n_tendons,
            n_starts=protocol.n_starts,
            n_points=protocol.n_points,
            robot_toml=robot_toml,
            robot_name=robot.name,
            protocol_json=protocol_json,
            split=split,
            seed=seed,
        )
    try:
        done = f["done"][...].astype(bool)
        todo = np.flatnonzero(~done)
        if max_new is not None:
            todo = todo[:max_new]
        seeds = spawn_seeds([seed, SPLITS.index(split)], C)  # train and test draw independently
        n_done = int(done.sum())
        if progress is not None:
            progress(n_done, C)
        items = [(robot_toml, protocol_json, targets[i], seeds[i]) for i in todo]
        if backend == "local" and len(items) * protocol.n_starts < min_parallel_clouds:
            backend = "serial"
        if chunksize is None:
            chunksize = chunk_size(len(items), backend, workers)
        for k, (pts, tips, starts, tens) in imap_tasks(
            _task,
            items,
            backend=backend,
            workers=workers,
            chunksize=chunksize,
            ray_address=ray_address,
        ):
            storage.write_config(f, int(todo[k]), pts, tips, starts, tens)
            n_done += 1
            if progress is not None:
                progress(n_done, C)
        finished = bool(np.all(f["done"][...]))
        if finished:
            storage.mark_complete(f)
            _report_over_max_tension(f, robot, out)
    finally:
        f.close()
    if finished:
        os.replace(part, out)
        return out
    return part


def _report_over_max_tension(f, robot, out) -> None:
    """Log how many arrivals exceed ``max_tension``, and in which targets (they are kept: they
    lie inside the protocol's box; ``riskplan dataset info`` lists them too)."""
    from riskplan.datasets.summary import over_max_tension

    over = over_max_tension(f["tensions"][...], robot.tension_limits)
    if over["arrivals"]:
        t = over["targets"]
        log.warning(
            "%s: %d of %d arrivals (%.1f %%) need more than max_tension (per tendon %s), in %d "
            "targets: %s%s (kept; `riskplan dataset info` lists them all)",
            out,
            over["arrivals"],
            over["of"],
            100 * over["fraction"],
            over["per_tendon"],
            len(t),
            t[:20],
            " ..." if len(t) > 20 else "",
        )


def generate_splits(
    robot, preset, stem, *, seed: int = 0, splits=("train", "test"), **kwargs
) -> dict[str, Path]:
    """Generate several splits, ``<stem>_train.h5`` and ``<stem>_test.h5`` (:func:`split_paths`).

    Each split uses the same ``seed``; the per-target seeds also depend on the split.

    Parameters
    ----------
    robot : str, os.PathLike or TendonRobot
        As in :func:`generate_dataset`.
    preset : str or Protocol
        The data-collection protocol.
    stem : str or os.PathLike
        File stem (a trailing ``.h5`` is dropped).
    seed : int
        Root seed.
    splits : tuple of str
        The splits to write.
    **kwargs
        Passed to :func:`generate_dataset`.

    Returns
    -------
    dict
        ``{split: path}``.
    """
    return {
        sp: generate_dataset(robot, preset, path, split=sp, seed=seed, **kwargs)
        for sp, path in split_paths(stem, splits).items()
    }


def split_paths(stem, splits=("train", "test")) -> dict[str, Path]:
    """The file of each split: ``data.h5`` (or ``data``) -> ``data_train.h5``, ``data_test.h5``.

    Parameters
    ----------
    stem : str or os.PathLike
        File stem (a trailing ``.h5`` is dropped).
    splits : tuple of str
        The splits.

    Returns
    -------
    dict
        ``{split: pathlib.Path}``.
    """
    stem = Path(stem)
    if stem.suffix == ".h5":
        stem = stem.with_suffix("")
    return {sp: stem.with_name(f"{stem.name}_{sp}.h5") for sp in splits}
