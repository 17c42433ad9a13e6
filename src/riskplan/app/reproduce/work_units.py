"""Work units of the resumable reproductions: the seed of a named part of a run
(:func:`_seed_for`) and pickled work products beside a ResultStore (:class:`BlobStore`).

Every stage of ``riskplan reproduce`` that stores plans or controllers (Fig. 6 of the
deformable paper, the calibration study, the needle study) keeps them here, and derives the
seed of each part from the root seed and the part's labels, so a rerun reads what a stopped
run finished and computes the rest with the same draws.
"""

from __future__ import annotations

import hashlib
import pickle
from pathlib import Path

import numpy as np

from riskplan.errors import DataFormatError

__all__ = ["BlobStore"]


class BlobStore:
    """Pickled work products (plans, controllers) beside a ResultStore, hash-checked.

    ``DIR/blobs/<key>.pkl`` holds the bytes; the ResultStore record ``blob.<key>`` holds their
    SHA-256, written after the file, so a blob without a record is simply recomputed and a
    blob whose bytes do not match its record raises :class:`DataFormatError` naming the file.
    Only files this store wrote are ever unpickled (the hash is checked first).
    """

    def __init__(self, store):
        self.store = store
        self.dir = Path(store.root) / "blobs"
        self.dir.mkdir(parents=True, exist_ok=True)

    def get(self, key: str):
        rec = self.store.get(f"blob.{key}")
        if rec is None:
            return None
        path = self.dir / f"{key}.pkl"
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise DataFormatError(f"{path}: results blob missing or unreadable ({exc})") from exc
        if hashlib.sha256(data).hexdigest() != rec["sha256"]:
            raise DataFormatError(f"{path}: corrupted results blob (content hash mismatch)")
        return pickle.loads(data)

    def put(self, key: str, obj) -> None:
        from riskplan.io import atomic_path

        data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        path = self.dir / f"{key}.pkl"
        with atomic_path(path) as tmp:
            Path(tmp).write_bytes(data)
        self.store.put(
            f"blob.{key}", {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
        )

    def get_or_compute(self, key: str, compute):
        found = self.get(key)
        if found is not None:
            return found
        obj = compute()
        self.put(key, obj)
        return obj


def _seed_for(seed: int, *labels) -> int:
    """A 63-bit seed for a named part of the run (stable across runs and backends)."""
    words = [int(seed)] + [
        int.from_bytes(hashlib.sha256(str(x).encode()).digest()[:4], "little") for x in labels
    ]
    return int(np.random.SeedSequence(words).generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def stage_map(backend, workers, ray_address, pool):
    """The map a stage runs its work units through: :func:`riskplan.parallel.imap_tasks` with
    the stage's backend and one unit per task (``chunksize=1``: units are seconds each, and a
    killed run keeps every finished one)."""
    from functools import partial

    from riskplan.parallel import imap_tasks

    return partial(
        imap_tasks,
        backend=backend,
        workers=workers,
        ray_address=ray_address,
        chunksize=1,
        pool=pool,
    )
