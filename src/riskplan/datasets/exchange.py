"""Point clouds in and out: a manifest of cloud files <-> riskplan's HDF5 data set.

Measured data (depth cameras on a real robot) reach training through :func:`import_dataset`;
:func:`export_dataset` writes a data set in the same layout, so the two are inverse.

Layout (a folder)::

    manifest.csv      one row per cloud (configuration, start)
    robot.toml        the robot (optional on import: ``robot=`` instead)
    dataset.json      protocol, split, seed, robot name (optional on import)
    clouds/c00000_s0.npy ...

Manifest columns (header row required, ``#`` lines are comments):

* ``config_id`` (integer; rows with the same id are clouds of one target configuration),
  ``start_id`` (integer ``0 .. S-1`` within a configuration), ``file`` (relative to the
  manifest's folder);
* the configuration, in the robot's tendon order: displacements ``d0 .. d{m-1}`` (m) and/or
  tensions ``tension0 .. tension{m-1}`` (N). With tensions only, displacements come from the
  robot model (:meth:`TendonRobot.displacements_for_tensions`); with displacements only, the
  stored arrival tensions are the model's (:meth:`TendonRobot.tensions_for_displacements`).
  The target (displacements, or tensions when no displacements are given) must be the same on
  every row of a configuration; with both, the tensions are each cloud's arrival tensions;
* optional ``start0 .. start{m-1}`` (the configuration the robot came from, m; default: the
  target) and ``tip_x, tip_y, tip_z`` (the measured tip, m, base frame; default: the model's tip
  at the target).

Cloud files: ``.npy`` (``(P, 3)`` array), ``.csv`` (three columns x, y, z; a header row is
allowed), ``.ply`` (through trimesh, already a dependency), ``.pcd`` (through pypcd4: small,
pure Python, reads PCL's ascii, binary and binary_compressed encodings; Open3D also reads both
formats but is a large install for two readers). Points are metres in the robot base frame.

Round trip: export writes float32 points as ``.npy``, binary ``.ply`` and binary ``.pcd``
bit for bit, ``.csv`` with 9 significant digits (enough to recover every float32), and the
manifest's float64 values with Python's shortest round-trip repr; so export then import gives
identical arrays and identical row digests in every format.

Checks on import, all before anything is written (errors name the file and the field):
every file exists and reads as finite ``(P, 3)`` numbers; every configuration has the same
starts ``0 .. S-1`` and the same target on each row; every cloud has ``P`` points (or at least
``n_points``, then a seeded subset is kept); the target lies within the robot's displacement
limits; every point lies within the robot's reach (:func:`riskplan.datasets.storage.reach_bound`),
and a cloud far beyond it in the proportion of millimetres to metres is said to be in
millimetres.
"""

from __future__ import annotations

import csv
import json
import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from riskplan._validation import check_count
from riskplan.errors import DataFormatError, InvalidInputError, MissingDependencyError

log = logging.getLogger(__name__)

FORMATS = ("npy", "ply", "pcd", "csv")
MANIFEST = "manifest.csv"
ROBOT_FILE = "robot.toml"
META_FILE = "dataset.json"
TIP_COLUMNS = ("tip_x", "tip_y", "tip_z")
# a cloud this many times beyond the robot's reach is in millimetres, not metres (the reach
# bound already has a factor 2 of slack, so 100 leaves a gap of 5 to the factor 1000)
MILLIMETRE_FACTOR = 100.0


@dataclass(frozen=True)
class ImportedClouds:
    """Validated arrays of an import, in the data-set schema (``C`` configurations, ``S`` starts,
    ``P`` points, ``m`` tendons)."""

    displacements: np.ndarray  # (C, m)
    points: np.ndarray  # (C, S, P, 3) float32
    tips: np.ndarray  # (C, S, 3)
    starts: np.ndarray  # (C, S, m)
    tensions: np.ndarray  # (C, S, m)
    config_ids: np.ndarray  # (C,) manifest ids, in file order of first appearance
    sources: dict  # which columns came from the manifest and which from the robot model


# ----------------------------------------------------------------------------- clouds
def read_cloud(path) -> np.ndarray:
    """Read one cloud file as ``(P, 3)`` float32 (``.npy``, ``.csv``, ``.ply``, ``.pcd``).

    Raises :class:`InvalidInputError` for a missing file or an unknown suffix and
    :class:`DataFormatError` naming the file for unreadable or non-finite content.
    """
    path = Path(path)
    ext = path.suffix.lower().lstrip(".")
    if ext not in FORMATS:
        raise InvalidInputError(f"{path}: unknown cloud format; expected one of {FORMATS}")
    if not path.is_file():
        raise InvalidInputError(f"{path}: cloud file not found")
    try:
        if ext == "npy":
            a = np.load(path, allow_pickle=False)
        elif ext == "csv":
            a = _read_csv_points(path)
        elif ext == "ply":
            import trimesh

            a = np.asarray(trimesh.load(path, process=False).vertices)
        else:
            a = _pypcd4().PointCloud.from_path(path).numpy(("x", "y", "z"))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise DataFormatError(f"{path}: not a readable {ext} point cloud ({exc})") from exc
    a = np.asarray(a)
    if a.ndim != 2 or a.shape[1] != 3 or a.dtype.kind not in "fiu":
        raise DataFormatError(f"{path}: expected (P, 3) numbers, got shape {a.shape} of {a.dtype}")
    if len(a) == 0:
        raise DataFormatError(f"{path}: the cloud has no points")
    if not np.all(np.isfinite(a)):
        bad = int(np.flatnonzero(~np.isfinite(a).all(axis=1))[0])
        raise DataFormatError(f"{path}: point {bad} is not finite ({a[bad].tolist()})")
    return a.astype(np.float32)


def write_cloud(path, points) -> None:
    """Write ``(P, 3)`` float32 points in the format of the suffix, losslessly (see module doc)."""
    from riskplan.io import atomic_path

    path = Path(path)
    ext = path.suffix.lower().lstrip(".")
    p = np.ascontiguousarray(points, dtype=np.float32)
    with atomic_path(path, suffix=path.suffix) as tmp:
        if ext == "npy":
            with open(tmp, "wb") as fh:
                np.save(fh, p, allow_pickle=False)
        elif ext == "csv":
            np.savetxt(tmp, p, fmt="%.9g", delimiter=",", header="x,y,z", comments="")
        elif ext == "ply":
            import trimesh

            tmp.write_bytes(trimesh.PointCloud(p).export(file_type="ply", encoding="binary"))
        elif ext == "pcd":
            _pypcd4().PointCloud.from_xyz_points(p).save(tmp)
        else:
            raise InvalidInputError(f"{path}: unknown cloud format; expected one of {FORMATS}")


def _read_csv_points(path: Path) -> np.ndarray:
    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        for n, row in enumerate(csv.reader(fh), start=1):
            if not row or row[0].lstrip().startswith("#"):
                continue
            try:
                rows.append([float(v) for v in row])
            except ValueError:
                if not rows and n == 1:  # a header row
                    continue
                raise ValueError(f"line {n}: not numbers: {row!r}") from None
    return np.array(rows, dtype=np.float64).reshape(-1, len(rows[0]) if rows else 3)


def _pypcd4():
    try:
        import pypcd4
    except ImportError as exc:
        raise MissingDependencyError(
            "pypcd4 is needed for .pcd clouds: pip install 'riskplan[io]'"
        ) from exc
    return pypcd4


# --------------------------------------------------------------------------- manifest
def _columns(header, m: int):
    have = set(header)
    for key in ("config_id", "start_id", "file"):
        if key not in have:
            raise DataFormatError(f"missing column {key!r} (header: {', '.join(header)})")
    groups = {
        "d": [f"d{i}" for i in range(m)],
        "tension": [f"tension{i}" for i in range(m)],
        "start": [f"start{i}" for i in range(m)],
        "tip": list(TIP_COLUMNS),
    }
    present = {}
    for g, cols in groups.items():
        n = sum(c in have for c in cols)
        if 0 < n < len(cols):
            missing = [c for c in cols if c not in have]
            raise DataFormatError(
                f"columns {', '.join(cols)}: {', '.join(missing)} missing (the robot has {m} tendons)"
            )
        present[g] = n == len(cols)
    known = {c for cols in groups.values() for c in cols}
    extra = [c for c in header if re.fullmatch(r"(d|tension|start)\d+", c) and c not in known]
    if extra:
        raise DataFormatError(
            f"column(s) {', '.join(extra)} do not fit the robot's {m} tendons (d0..d{m - 1})"
        )
    if not (present["d"] or present["tension"]):
        raise DataFormatError(
            f"the configuration is missing: give displacements d0..d{m - 1} (m) or tensions "
            f"tension0..tension{m - 1} (N)"
        )
    return groups, present


def read_manifest(path, m: int) -> tuple[list[dict], dict, dict]:
    """Rows of a manifest as dicts of typed values, with the column groups present.

    Raises :class:`DataFormatError` naming the manifest, the line and the field.
    """
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"manifest not found: {path}")
    with open(path, newline="", encoding="utf-8") as fh:
        lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
    reader = csv.DictReader(lines)
    header = [h.strip() for h in (reader.fieldnames or [])]
    reader.fieldnames = header
    try:
        groups, present = _columns(header, m)
    except DataFormatError as exc:
        raise DataFormatError(f"{path}: {exc}") from None
    rows = []
    for n, raw in enumerate(reader, start=2):
        row = {"line": n}
        for key in ("config_id", "start_id"):
            try:
                value = int(str(raw[key]).strip())
            except (TypeError, ValueError):
                value = raw[key]  # not an integer: check_count names it
            where = f"{path}, line {n}, field {key!r}"
            row[key] = check_count(value, where, None, error=DataFormatError)
        row["file"] = str(raw["file"] or "").strip()
        if not row["file"]:
            raise DataFormatError(f"{path}, line {n}, field 'file': empty")
        for g, cols in groups.items():
            if not present[g]:
                continue
            vals = []
            for c in cols:
                try:
                    v = float(str(raw[c]).strip())
                except (TypeError, ValueError):
                    v = np.nan
                if not np.isfinite(v):
                    raise DataFormatError(
                        f"{path}, line {n}, field {c!r}: expected a finite number, got {raw[c]!r}"
                    )
                vals.append(v)
            row[g] = np.array(vals)
        rows.append(row)
    if not rows:
        raise DataFormatError(f"{path}: the manifest lists no clouds")
    return rows, groups, present


# ----------------------------------------------------------------------------- import
def load_manifest_clouds(
    manifest, robot, *, n_points: int | None = None, scale: float = 1.0, seed: int = 0
) -> ImportedClouds:
    """Read and check every cloud of a manifest against ``robot`` (see the module doc).

    ``scale`` multiplies the cloud coordinates (0.001 for millimetres); ``n_points`` keeps a
    seeded subset of that many points of every cloud (default: all clouds must have the same
    count). Nothing is written.
    """
    from riskplan.datasets.storage import REACH_FACTOR, reach_bound

    manifest = Path(manifest)
    m = robot.n_tendons
    if not (np.isfinite(scale) and scale > 0):
        raise InvalidInputError(f"scale: expected a positive number, got {scale!r}")
    rows, groups, present = read_manifest(manifest, m)
    where = manifest.parent

    # group rows by configuration, in order of first appearance
    by_config: dict[int, list[dict]] = {}
    for r in rows:
        by_config.setdefault(r["config_id"], []).append(r)
    ids = np.array(list(by_config), dtype=np.int64)
    S = len(by_config[int(ids[0])])
    for cid, rs in by_config.items():
        starts = sorted(r["start_id"] for r in rs)
        if starts != list(range(len(rs))) or len(rs) != S:
            raise DataFormatError(
                f"{manifest}, config_id {cid}: start_id values {starts}; every configuration needs "
                f"the same starts 0..{S - 1} (configuration {int(ids[0])} has {S})"
            )
        rs.sort(key=lambda r: r["start_id"])
        # the target: displacements when given (tensions are then each cloud's arrival
        # tensions, which differ by start), else the tensions
        for g in ("d",) if present["d"] else ("tension",):
            if present[g]:
                first = rs[0][g]
                for r in rs[1:]:
                    if not np.array_equal(r[g], first):
                        raise DataFormatError(
                            f"{manifest}, line {r['line']}, fields {groups[g][0]}..{groups[g][-1]}: "
                            f"configuration {cid} has another target on line {rs[0]['line']}"
                        )

    # the targets, through the robot model where a column group is absent
    C = len(ids)
    lines = [by_config[int(c)][0]["line"] for c in ids]
    if present["d"]:
        disp = np.stack([by_config[int(c)][0]["d"] for c in ids])
        _check_limits(robot, disp, lines, manifest, "displacements", groups["d"])
    else:
        tau = np.stack([by_config[int(c)][0]["tension"] for c in ids])
        _check_limits(robot, tau, lines, manifest, "tensions", groups["tension"])
        disp = robot.displacements_for_tensions(tau)
        _check_limits(robot, disp, lines, manifest, "displacements", groups["tension"])
    if present["tension"]:
        tensions = np.stack([[r["tension"] for r in by_config[int(c)]] for c in ids])
    else:
        tensions = np.repeat(robot.tensions_for_displacements(disp)[:, None], S, axis=1)
    if present["start"]:
        starts = np.stack([[r["start"] for r in by_config[int(c)]] for c in ids])
    else:
        starts = np.repeat(disp[:, None], S, axis=1)
    if present["tip"]:
        tips = np.stack([[r["tip"] for r in by_config[int(c)]] for c in ids])
    else:
        tips = np.repeat(robot.solve_displacements(disp).tip[:, None], S, axis=1)

    # the clouds
    reach = reach_bound(robot.toml_text())
    rng = np.random.default_rng(seed)
    clouds = []
    for c in ids:
        for r in by_config[int(c)]:
            f = (
                (where / r["file"]).resolve()
                if not Path(r["file"]).is_absolute()
                else Path(r["file"])
            )
            if not f.is_file():
                raise InvalidInputError(
                    f"{manifest}, line {r['line']}, field 'file': {f} not found"
                )
            p = read_cloud(f)
            if scale != 1.0:
                p = (p.astype(np.float64) * scale).astype(np.float32)
            if reach is not None:
                dist = float(np.sqrt((p.astype(np.float64) ** 2).sum(-1)).max())
                if dist > reach:
                    hint = (
                        "; the coordinates look like millimetres where metres are expected (scale 0.001)"
                        if dist > MILLIMETRE_FACTOR * reach
                        else "; are the points in the robot base frame?"
                    )
                    raise DataFormatError(
                        f"{f} (manifest line {r['line']}): a point lies {dist:.4g} m from the robot base, "
                        f"beyond the robot's reach ({reach / REACH_FACTOR:.4g} m, limit {reach:.4g} m){hint}"
                    )
            clouds.append((f, r["line"], p))
    counts = np.array([len(p) for _, _, p in clouds])
    if n_points is None:
        P = int(np.bincount(counts).argmax())
        odd = np.flatnonzero(counts != P)
        if odd.size:
            f, line, p = clouds[int(odd[0])]
            raise DataFormatError(
                f"{f} (manifest line {line}): {len(p)} points, but most clouds have {P}; "
                "give n_points (--points) to keep that many of every cloud"
            )
    else:
        P = check_count(n_points, "n_points", 1, integral=True)
        short = np.flatnonzero(counts < P)
        if short.size:
            f, line, p = clouds[int(short[0])]
            raise DataFormatError(
                f"{f} (manifest line {line}): {len(p)} points, fewer than the {P} asked for"
            )
        clouds = [
            (f, line, p if len(p) == P else p[np.sort(rng.choice(len(p), P, replace=False))])
            for f, line, p in clouds
        ]
    points = np.stack([p for _, _, p in clouds]).reshape(C, S, P, 3)
    sources = {
        "displacements": "manifest" if present["d"] else "robot model (from tensions)",
        "tensions": "manifest" if present["tension"] else "robot model (from displacements)",
        "starts": "manifest" if present["start"] else "the target (no start given)",
        "tips": "manifest" if present["tip"] else "robot model at the target",
    }
    return ImportedClouds(disp, points, tips, starts, tensions, ids, sources)


def _check_limits(robot, values, lines, manifest, what, cols):
    lim = robot.displacement_limits if what == "displacements" else None
    for i, v in enumerate(values):
        if lim is not None:
            bad = np.flatnonzero((v < lim[:, 0]) | (v > lim[:, 1]))
            rng_text = [f"[{lo:.4g}, {hi:.4g}] m" for lo, hi in lim]
        else:
            tmax = robot.tension_limits
            bad = np.flatnonzero((v < 0) | (v > tmax))
            rng_text = [f"[0, {t:.4g}] N" for t in tmax]
        if bad.size:
            j = int(bad[0])
            got = f"{v[j]:.6g}" if cols[j].startswith(what[0]) else f"displacement {v[j]:.6g} m"
            raise InvalidInputError(
                f"{manifest}, line {lines[i]}, field {cols[j]!r}: {got} outside the robot's "
                f"{what} limits {rng_text[j]}"
            )


def import_dataset(
    manifest,
    out,
    *,
    robot=None,
    n_points: int | None = None,
    scale: float = 1.0,
    seed: int = 0,
    overwrite: bool = False,
) -> Path:
    """Read the clouds a manifest lists, check them, and write a riskplan data set (HDF5).

    ``robot``: a :class:`TendonRobot`, a name or a TOML file; default ``robot.toml`` beside the
    manifest. ``dataset.json`` beside the manifest, when present, gives the protocol, split and
    seed recorded in the file (an export's); otherwise the protocol records the import. Every
    check runs before the output is created; the file is written atomically.
    """
    from riskplan.datasets.storage import create_file, mark_complete, write_config
    from riskplan.io import atomic_path, check_output_file
    from riskplan.robots import load_robot

    manifest = Path(manifest)
    out = check_output_file(out, "out")
    if out.exists() and not overwrite:
        raise InvalidInputError(
            f"out: {out} exists; pass overwrite=True (--overwrite) to replace it"
        )
    if robot is None:
        rf = manifest.parent / ROBOT_FILE
        if not rf.is_file():
            raise InvalidInputError(
                f"{manifest}: no {ROBOT_FILE} beside the manifest; name the robot (--robot NAME|FILE)"
            )
        robot = rf
    robot = load_robot(robot)
    meta = {}
    mf = manifest.parent / META_FILE
    if mf.is_file():
        try:
            meta = json.loads(mf.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise DataFormatError(f"{mf}: not readable JSON ({exc})") from exc
    data = load_manifest_clouds(manifest, robot, n_points=n_points, scale=scale, seed=seed)
    C, S, P, _ = data.points.shape
    protocol = meta.get("protocol") or {
        "kind": "imported",
        "manifest": manifest.name,
        "n_starts": S,
        "n_points": P,
        "sources": data.sources,
    }
    with atomic_path(out, suffix=".h5") as tmp:
        f = create_file(
            tmp,
            displacements=data.displacements,
            n_starts=S,
            n_points=P,
            robot_toml=robot.toml_text(),
            robot_name=str(meta.get("robot_name", robot.name)),
            protocol_json=json.dumps(protocol, sort_keys=True),
            split=str(meta.get("split", "imported")),
            seed=int(meta.get("seed", seed)),
        )
        with f:
            f.attrs["imported_from"] = manifest.name
            f.attrs["config_ids"] = data.config_ids
            for i in range(C):
                write_config(f, i, data.points[i], data.tips[i], data.starts[i], data.tensions[i])
            mark_complete(f)
    log.info("imported %d configurations x %d clouds x %d points -> %s", C, S, P, out)
    return out


# ----------------------------------------------------------------------------- export
def export_dataset(path, out_dir, *, fmt: str = "npy", overwrite: bool = False) -> Path:
    """Write a data set as a manifest, ``robot.toml``, ``dataset.json`` and one cloud file per
    (configuration, start) in ``fmt`` (``npy``, ``ply``, ``pcd``, ``csv``). Returns the manifest.

    Only finished configurations are written. :func:`import_dataset` on the manifest rebuilds the
    same arrays and row digests.
    """
    from riskplan.datasets.storage import load_dataset
    from riskplan.io import check_output_folder, write_json_atomic, write_text_atomic

    if fmt not in FORMATS:
        raise InvalidInputError(f"format: expected one of {FORMATS}, got {fmt!r}")
    out_dir = check_output_folder(out_dir, "out")
    man = out_dir / MANIFEST
    if man.exists() and not overwrite:
        raise InvalidInputError(
            f"out: {man} exists; pass overwrite=True (--overwrite) to replace it"
        )
    ds = load_dataset(path)
    m = ds.n_tendons
    header = (
        ["config_id", "start_id", "file"]
        + [f"d{i}" for i in range(m)]
        + [f"tension{i}" for i in range(m)]
        + [f"start{i}" for i in range(m)]
        + list(TIP_COLUMNS)
    )
    rows = [",".join(header)]
    (out_dir / "clouds").mkdir(parents=True, exist_ok=True)
    for c in np.flatnonzero(ds.done):
        for s in range(ds.n_starts):
            rel = f"clouds/c{int(c):05d}_s{s}.{fmt}"
            write_cloud(out_dir / rel, ds.points[c, s])
            vals = [
                *ds.displacements[c],
                *ds.tensions[c, s],
                *ds.starts[c, s],
                *ds.tips[c, s],
            ]
            rows.append(",".join([str(int(c)), str(s), rel] + [repr(float(v)) for v in vals]))
    write_text_atomic(out_dir / ROBOT_FILE, str(ds.metadata["robot_toml"]))
    write_json_atomic(
        out_dir / META_FILE,
        {
            "robot_name": ds.metadata.get("robot_name", ""),
            "protocol": ds.metadata["protocol"],
            "split": ds.metadata.get("split", ""),
            "seed": ds.metadata.get("seed", 0),
            "source": Path(path).name,
            "cloud_format": fmt,
            "units": {
                "points": "m, robot base frame",
                "d": "m",
                "tension": "N",
                "start": "m",
                "tip": "m",
            },
        },
    )
    write_text_atomic(man, "\n".join(rows) + "\n")
    return man
