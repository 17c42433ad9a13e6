"""A resumable store of finished work for long experiments (``riskplan reproduce``).

Each finished unit of work (one batch of executions, one trained model's numbers) is written
as its own JSON record ``DIR/records/<key>.json`` as soon as it completes, atomically, with a
SHA-256 of its canonical payload and the fingerprint of the run configuration. Rerunning the
same command reads the valid records and computes only what is missing, so an interrupted run
continues and ends with the same results as an uninterrupted one.

What is never silently mixed in:

* a record whose hash does not match its payload (truncated, edited, bit rot) raises
  :class:`~riskplan.errors.DataFormatError` naming the file;
* a record (or the whole store) written by a run with a different configuration (other seed,
  scale, paper, riskplan version) raises the same error: the user chooses another ``--out``
  or deletes the folder.

Records are plain JSON so a person can read them; arrays go in as lists.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.io import canonical_json, write_text_atomic

__all__ = ["ResultStore", "canonical_json", "fingerprint"]

_KEY = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.=-]{0,200}$")
FORMAT = "riskplan-results/1"


def fingerprint(config: dict) -> str:
    """SHA-256 (hex, 16 characters) of a run configuration."""
    return hashlib.sha256(canonical_json(config).encode()).hexdigest()[:16]


def _digest(payload: Any) -> str:
    return hashlib.sha256(canonical_json(payload).encode()).hexdigest()


class ResultStore:
    """Records of finished work under ``root`` for one run configuration.

    Parameters
    ----------
    root:
        Folder of the store (created if missing).
    config:
        JSON-serialisable description of the run (paper, scale, seed, version, ...). A store
        created with one configuration refuses records of another.
    """

    def __init__(self, root, config: dict):
        self.root = Path(root)
        try:
            self.fingerprint = fingerprint(config)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(
                f"config: expected JSON-serialisable values, got {config!r}"
            ) from exc
        self.config = config
        self.records_dir = self.root / "records"
        manifest = self.root / "manifest.json"
        if manifest.exists():
            try:
                meta = json.loads(manifest.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise DataFormatError(
                    f"{manifest}: not a readable results manifest ({exc})"
                ) from exc
            if meta.get("format") != FORMAT or meta.get("fingerprint") != self.fingerprint:
                raise DataFormatError(
                    f"{self.root}: holds results of another run configuration "
                    f"({meta.get('config')!r}); use another output folder or delete this one"
                )
        else:
            self.records_dir.mkdir(parents=True, exist_ok=True)
            write_text_atomic(
                manifest,
                json.dumps(
                    {"format": FORMAT, "fingerprint": self.fingerprint, "config": config}, indent=1
                ),
            )
        self.records_dir.mkdir(parents=True, exist_ok=True)

    def _path(self, key: str) -> Path:
        if not isinstance(key, str) or not _KEY.match(key):
            raise InvalidInputError(
                f"key: expected letters, digits and _.=- (at most 201 characters), got {key!r}"
            )
        return self.records_dir / f"{key}.json"

    def __contains__(self, key: str) -> bool:
        return self.get(key) is not None

    def get(self, key: str) -> Any | None:
        """The payload stored under ``key``, ``None`` if absent; a corrupt record raises."""
        path = self._path(key)
        if not path.exists():
            return None
        try:
            rec = json.loads(path.read_text(encoding="utf-8"))
            payload, digest, fp = rec["payload"], rec["sha256"], rec["fingerprint"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise DataFormatError(
                f"{path}: corrupted results record ({type(exc).__name__}: {exc})"
            ) from exc
        if fp != self.fingerprint:
            raise DataFormatError(
                f"{path}: record of another run configuration (fingerprint {fp!r})"
            )
        if _digest(payload) != digest:
            raise DataFormatError(f"{path}: corrupted results record (content hash mismatch)")
        return payload

    def put(self, key: str, payload: Any) -> None:
        """Write ``payload`` under ``key`` atomically (replacing an earlier record)."""
        path = self._path(key)
        try:
            text = json.dumps(
                {
                    "key": key,
                    "fingerprint": self.fingerprint,
                    "sha256": _digest(payload),
                    "payload": payload,
                },
                allow_nan=False,
            )
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(
                f"payload of {key!r}: expected finite JSON-serialisable values ({exc})"
            ) from exc
        write_text_atomic(path, text)

    def get_or_compute(self, key: str, compute: Callable[[], Any]) -> Any:
        """The stored payload of ``key``, or ``compute()`` stored then returned."""
        found = self.get(key)
        if found is not None:
            return found
        value = compute()
        self.put(key, value)
        return value

    def keys(self) -> list[str]:
        """Keys of the records present (not verified; :meth:`get` verifies)."""
        return sorted(p.stem for p in self.records_dir.glob("*.json"))
