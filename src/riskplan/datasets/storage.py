"""HDF5 storage of point-cloud data sets (schema in ``docs/datasets.md``).

Attributes: ``format="riskplan-dataset"``, ``format_version=1``, ``riskplan_version``,
``robot_toml``, ``robot_name``, ``protocol`` (JSON), ``split``, ``seed``, ``created``,
``complete``. Data sets: ``displacements (C, m) float64``, ``points (C, S, P, 3) float32``,
``tips (C, S, 3) float64``, ``starts (C, S, m) float64``, ``tensions (C, S, m) float64``
(diagnostic: tendon tensions on arrival), ``done (C,) bool``.

Safe writes: a generation writes ``<out>.partial``; all data sets are allocated in full
when the file is created (contiguous storage, so later writes touch raw data only, never
HDF5 metadata). Each finished configuration's rows are written and flushed before its
``done`` flag is set and flushed, so a killed run leaves at worst rows without their flag,
which a resumed run recomputes. When every flag is set, ``complete`` is set and the file is
renamed atomically onto ``<out>``.

Integrity: ``row_sha256 (C, 32) uint8`` holds, per configuration, the SHA-256 of its rows
(``displacements[i]`` as float64, ``points[i]`` as float32, ``tips[i]``, ``starts[i]``,
``tensions[i]`` as float64, little-endian), written with the rows before the ``done`` flag.
:func:`load_dataset` recomputes it for every finished configuration and raises
:class:`DataFormatError` naming the configurations whose bytes changed. An all-zero digest means
"not recorded" (rows of a partial file begun by a riskplan without hashes). Points are also
range-checked against the robot's reach (:func:`reach_bound`): flipped exponent bits turn
millimetres into kilometres, which no hash-less reader would notice.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import riskplan
from riskplan.errors import DataFormatError

log = logging.getLogger(__name__)

FORMAT = "riskplan-dataset"
FORMAT_VERSION = 1
DATASETS = ("displacements", "points", "tips", "starts", "tensions", "done")
HASHES = "row_sha256"
# points may lie at most this factor times the robot's reach (length + disk radius) from the
# base origin: generous for camera noise and rod extension, tight enough to catch flipped bits
REACH_FACTOR = 2.0


def row_digest(displacements, points, tips, starts, tensions) -> np.ndarray:
    """SHA-256 ``(32,) uint8`` of one configuration's rows, in the dtypes they are stored in."""
    import hashlib

    h = hashlib.sha256()
    for a, dt in (
        (displacements, "<f8"),
        (points, "<f4"),
        (tips, "<f8"),
        (starts, "<f8"),
        (tensions, "<f8"),
    ):
        h.update(np.ascontiguousarray(a, dtype=dt).tobytes())
    return np.frombuffer(h.digest(), dtype=np.uint8).copy()


def reach_bound(robot_toml: str) -> float | None:
    """Largest distance from the base origin a point of this robot may have (m), or ``None`` when
    the stored description is not a full robot (e.g. synthetic test data)."""
    if not robot_toml:
        return None
    try:
        from riskplan.robots.description import parse_robot_toml

        p = parse_robot_toml(robot_toml)
    except Exception:  # not a robot description: nothing to compare against
        return None
    r = max(
        p.disks.radius, p.backbone.outer_radius, *(max(abs(c) for c in t.radius) for t in p.tendons)
    )
    return REACH_FACTOR * (p.backbone.length + r)


def _attr(f, key):
    v = f.attrs.get(key)
    if isinstance(v, bytes):
        v = v.decode()
    if isinstance(v, np.generic):
        v = v.item()
    return v


def partial_path(out) -> Path:
    out = Path(out)
    return out.with_name(out.name + ".partial")


def create_file(
    path,
    *,
    displacements,
    n_starts: int,
    n_points: int,
    n_tendons: int | None = None,
    robot_toml: str,
    robot_name: str,
    protocol_json: str,
    split: str,
    seed: int,
):
    """Create a data-set file with every data set allocated (``done`` all False); returns the open h5py File.

    ``displacements (C, n_config)``: the target configurations (tendon displacements, then base
    rotation and retraction for robots that have them); ``n_tendons`` (default: all columns)
    the width of ``tensions``.
    """
    import h5py

    C, m = displacements.shape
    mt = m if n_tendons is None else int(n_tendons)
    f = h5py.File(path, "w")
    try:
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["riskplan_version"] = riskplan.__version__
        f.attrs["robot_toml"] = robot_toml
        f.attrs["robot_name"] = robot_name
        f.attrs["protocol"] = protocol_json
        f.attrs["split"] = split
        f.attrs["seed"] = int(seed)
        f.attrs["created"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        f.attrs["complete"] = False
        f.create_dataset("displacements", data=np.asarray(displacements, dtype=np.float64))
        # Writing zeros allocates the contiguous storage now: later row writes never change metadata.
        f.create_dataset("points", data=np.zeros((C, n_starts, n_points, 3), dtype=np.float32))
        f.create_dataset("tips", data=np.zeros((C, n_starts, 3), dtype=np.float64))
        f.create_dataset("starts", data=np.zeros((C, n_starts, m), dtype=np.float64))
        f.create_dataset("tensions", data=np.zeros((C, n_starts, mt), dtype=np.float64))
        f.create_dataset("done", data=np.zeros(C, dtype=bool))
        f.create_dataset(HASHES, data=np.zeros((C, 32), dtype=np.uint8))
        f["points"].attrs["units"] = "m"
        f["points"].attrs["frame"] = "robot base"
        f["displacements"].attrs["units"] = "m"
        f["tips"].attrs["units"] = "m"
        f["starts"].attrs["units"] = "m"
        f["tensions"].attrs["units"] = "N"
        f.flush()
    except BaseException:
        f.close()
        raise
    return f


def write_config(f, i: int, points, tips, starts, tensions) -> None:
    """Write configuration ``i``'s rows and their digest, flush, then set and flush its ``done`` flag."""
    points = np.asarray(points, dtype=np.float32)
    f["points"][i] = points
    f["tips"][i] = tips
    f["starts"][i] = starts
    f["tensions"][i] = tensions
    if HASHES in f:
        f[HASHES][i] = row_digest(f["displacements"][i], points, tips, starts, tensions)
    f.flush()
    f["done"][i] = True
    f.flush()


def mark_complete(f) -> None:
    f.attrs["complete"] = True
    f.attrs["completed"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    f.flush()


def check_header(f, path) -> dict:
    """Validate the format attributes and data-set shapes; return the attributes as a dict."""
    fmt = _attr(f, "format")
    if fmt != FORMAT:
        raise DataFormatError(
            f"data set {str(path)!r}: attribute format={fmt!r}, expected {FORMAT!r}"
        )
    ver = _attr(f, "format_version")
    if ver != FORMAT_VERSION:
        raise DataFormatError(
            f"data set {str(path)!r}: format_version={ver!r}, this riskplan reads version {FORMAT_VERSION}"
        )
    for key in ("robot_toml", "robot_name", "protocol", "seed"):
        if key not in f.attrs:
            raise DataFormatError(f"data set {str(path)!r}: missing attribute {key!r}")
    for key in DATASETS:
        if key not in f:
            raise DataFormatError(f"data set {str(path)!r}: missing data set {key!r}")
    C, m = f["displacements"].shape if f["displacements"].ndim == 2 else (None, None)
    if C is None:
        raise DataFormatError(
            f"data set {str(path)!r}: displacements has shape {f['displacements'].shape}, expected (C, m)"
        )
    ps = f["points"].shape
    if len(ps) != 4 or ps[0] != C or ps[3] != 3:
        raise DataFormatError(
            f"data set {str(path)!r}: points has shape {ps}, expected (C={C}, S, P, 3)"
        )
    S = ps[1]
    # tensions hold the tendons only: fewer columns than the configuration of a robot with base
    # rotation/retraction
    mt = (
        f["tensions"].shape[-1]
        if f["tensions"].ndim == 3 and 1 <= f["tensions"].shape[-1] <= m
        else m
    )
    shapes = [("tips", (C, S, 3)), ("starts", (C, S, m)), ("tensions", (C, S, mt)), ("done", (C,))]
    if HASHES in f:
        shapes.append((HASHES, (C, 32)))
    for key, want in shapes:
        if f[key].shape != want:
            raise DataFormatError(
                f"data set {str(path)!r}: {key} has shape {f[key].shape}, expected {want}"
            )
    try:
        protocol = json.loads(_attr(f, "protocol"))
    except (TypeError, json.JSONDecodeError) as exc:
        raise DataFormatError(
            f"data set {str(path)!r}: attribute protocol is not valid JSON ({exc})"
        ) from exc
    meta = {k: _attr(f, k) for k in f.attrs}
    meta["protocol"] = protocol
    return meta


def open_existing(path):
    """Open an existing data-set file for reading and writing (resumption); validates the header."""
    import h5py

    try:
        f = h5py.File(path, "r+")
    except OSError as exc:
        raise DataFormatError(
            f"partial data set {str(path)!r} cannot be opened ({exc}); delete it to start the generation afresh"
        ) from exc
    try:
        check_header(f, path)
    except BaseException:
        f.close()
        raise
    return f


@dataclass(eq=False)
class Dataset:
    """A point-cloud data set read from HDF5.

    Attributes
    ----------
    displacements: ``(C, m)`` target tendon displacements (m).
    points: ``(C, S, P, 3)`` float32 clouds, base frame (m); ``S`` starts per target.
    tips: ``(C, S, 3)`` true tip positions on arrival (m, base frame).
    starts: ``(C, S, m)`` starting configurations (m).
    tensions: ``(C, S, m)`` tendon tensions on arrival (N).
    done: ``(C,)`` which configurations have data (all True in a complete file).
    metadata: the file attributes (``protocol`` parsed from JSON).
    path: the file read.
    """

    displacements: np.ndarray
    points: np.ndarray
    tips: np.ndarray
    starts: np.ndarray
    tensions: np.ndarray
    done: np.ndarray
    metadata: dict
    path: str = ""
    _robot: object = field(default=None, repr=False)

    @property
    def n_configs(self) -> int:
        return int(self.displacements.shape[0])

    @property
    def n_starts(self) -> int:
        return int(self.points.shape[1])

    @property
    def n_points(self) -> int:
        return int(self.points.shape[2])

    @property
    def n_tendons(self) -> int:
        return int(self.displacements.shape[1])

    @property
    def complete(self) -> bool:
        return bool(self.metadata.get("complete", False)) and bool(np.all(self.done))

    @property
    def protocol(self):
        from riskplan.datasets.protocol import Protocol

        return Protocol.from_json(json.dumps(self.metadata["protocol"]))

    @property
    def robot(self):
        """The robot rebuilt from the stored TOML (:class:`riskplan.robots.TendonRobot`)."""
        if self._robot is None:
            from riskplan.robots import robot_from_toml

            self._robot = robot_from_toml(self.metadata["robot_toml"])
        return self._robot

    def cloud(self, i: int) -> np.ndarray:
        """All points of configuration ``i`` (every start's cloud together).

        Parameters
        ----------
        i : int
            Configuration index, ``0 <= i < C``.

        Returns
        -------
        numpy.ndarray of float32, (S * P, 3)
            Base frame, m.
        """
        return self.points[i].reshape(-1, 3)

    def tip_spread(self) -> np.ndarray:
        """Spread of the arrival tips per target: the hysteresis-driven scatter of the data.

        Returns
        -------
        numpy.ndarray, (C,)
            RMS distance of the ``S`` arrival tips from their mean (m).
        """
        d = self.tips - self.tips.mean(axis=1, keepdims=True)
        return np.sqrt((d**2).sum(-1).mean(-1))


def verify_rows(arrays: dict, digests, meta: dict, path) -> None:
    """Check finished rows: finite, recorded digests match, points within the robot's reach.

    Raises :class:`DataFormatError` naming the first configurations that fail.
    """
    done = np.flatnonzero(arrays["done"])
    for key in ("displacements", "points", "tips", "starts", "tensions"):
        a = arrays[key][done]
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise DataFormatError(f"data set {str(path)!r}: {key} contain NaN or inf")
    if digests is None:
        log.warning(
            "data set %s has no row digests (written before they existed): integrity not checked",
            path,
        )
    else:
        recorded = digests[done].any(axis=1)
        bad = [
            int(i)
            for i, rec in zip(done, recorded)
            if rec
            and not np.array_equal(
                digests[i],
                row_digest(
                    arrays["displacements"][i],
                    arrays["points"][i],
                    arrays["tips"][i],
                    arrays["starts"][i],
                    arrays["tensions"][i],
                ),
            )
        ]
        if bad:
            raise DataFormatError(
                f"data set {str(path)!r}: {len(bad)} configuration(s) do not match their SHA-256 digest "
                f"(first {bad[:5]}); the file is corrupted - regenerate it"
            )
        if not recorded.all():
            log.warning(
                "data set %s: %d configuration(s) carry no digest", path, int((~recorded).sum())
            )
    reach = reach_bound(str(meta.get("robot_toml", "")))
    if reach is not None and done.size:
        r = np.sqrt((arrays["points"][done].astype(np.float64) ** 2).sum(-1))
        if r.max() > reach:
            c = int(done[np.unravel_index(int(np.argmax(r)), r.shape)[0]])
            raise DataFormatError(
                f"data set {str(path)!r}: a point of configuration {c} lies {r.max():.4g} m from the robot base, "
                f"beyond the robot's reach ({reach / REACH_FACTOR:.4g} m, limit {reach:.4g} m); the file is corrupted"
            )


def load_dataset(path) -> Dataset:
    """Read a data-set file; raise :class:`DataFormatError` naming the problem if it is not one.

    The file must carry ``format="riskplan-dataset"`` and a supported ``format_version`` and
    every data set of the schema with consistent shapes; points must be finite.

    Parameters
    ----------
    path : str or os.PathLike
        The HDF5 file.

    Returns
    -------
    Dataset
        The data set with its metadata.
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"data set {str(path)!r}: no such file")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise DataFormatError(f"data set {str(path)!r}: not a readable HDF5 file ({exc})") from exc
    with f:
        meta = check_header(f, path)
        try:
            arrays = {k: f[k][...] for k in DATASETS}
            digests = f[HASHES][...] if HASHES in f else None
        except (OSError, TypeError, ValueError) as exc:  # h5py: unreadable chunk, string-typed data
            raise DataFormatError(
                f"data set {str(path)!r}: cannot read its arrays ({exc})"
            ) from exc
    for key in DATASETS:
        kind = arrays[key].dtype.kind
        if kind not in ("b" if key == "done" else "fiu"):
            raise DataFormatError(
                f"data set {str(path)!r}: {key} has dtype {arrays[key].dtype}, expected numbers"
            )
    arrays["done"] = arrays["done"].astype(bool)
    verify_rows(arrays, digests, meta, path)
    return Dataset(
        displacements=arrays["displacements"].astype(np.float64),
        points=arrays["points"],
        tips=arrays["tips"],
        starts=arrays["starts"],
        tensions=arrays["tensions"],
        done=arrays["done"].astype(bool),
        metadata=meta,
        path=str(path),
    )
