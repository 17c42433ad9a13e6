"""Atomic file writes: write to a temporary file beside the target, then rename.

A reader never sees a half-written file, and an interrupted write leaves the old
file (if any) intact.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

__all__ = [
    "atomic_path",
    "canonical_json",
    "check_output_file",
    "check_output_folder",
    "output_lock",
    "read_file_with",
    "read_json_object",
    "write_json_atomic",
    "write_text_atomic",
]


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path in the target's folder; rename it onto ``path`` on success.

    On an exception the temporary file is removed and ``path`` is untouched.

    Parameters
    ----------
    path : str or os.PathLike
        The target file; its folder is created.
    suffix : str, optional
        Suffix of the temporary file (default ``.tmp``).

    Yields
    ------
    pathlib.Path
        The temporary path to write.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or ".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    # mkstemp creates 0600; give the result the mode an ordinary open() would (0666 & ~umask).
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def check_output_folder(path, name: str = "out") -> Path:
    """Raise :class:`~riskplan.errors.InvalidInputError` unless ``path`` can be (or is) a folder:
    it must not be an existing file, nor lie below one. Call before any work is done.

    Parameters
    ----------
    path : str or os.PathLike
        The folder.
    name : str
        The option that gave it, for messages.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    from riskplan.errors import InvalidInputError

    path = Path(path)
    for p in (path, *path.parents):
        if p.exists() and not p.is_dir():
            what = (
                "is an existing file" if p == path else f"lies below {str(p)!r}, an existing file"
            )
            raise InvalidInputError(f"{name}: {str(path)!r} {what}; expected a folder")
        if p.exists():
            break
    return path


def check_output_file(path, name: str = "out") -> Path:
    """Raise :class:`~riskplan.errors.InvalidInputError` if ``path`` is a folder or lies below a file.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    name : str
        The option that gave it, for messages.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    from riskplan.errors import InvalidInputError

    path = Path(path)
    if path.is_dir():
        raise InvalidInputError(f"{name}: {str(path)!r} is a folder; expected a file name")
    check_output_folder(path.parent, name)
    return path


def read_json_object(path) -> dict:
    """A JSON file that must hold one object.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    dict
        Its object. A missing file raises :class:`~riskplan.errors.InvalidInputError`; an
        unreadable one, or one that is not a JSON object,
        :class:`~riskplan.errors.DataFormatError`, naming the path.
    """
    from riskplan.errors import DataFormatError, InvalidInputError

    path = Path(path)
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise InvalidInputError(f"file not found: {path}") from exc
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(f"{path}: not a readable JSON file ({exc})") from exc
    if not isinstance(meta, dict):
        raise DataFormatError(f"{path}: expected a JSON object")
    return meta


def read_file_with(path, read, what: str, *, error=None, hint: str = ""):
    """``read(path)`` for an existing file, with what can go wrong named in riskplan's terms.

    Third-party readers (trimesh, torch) raise many exception types for damaged files; here
    each becomes one error that names the file.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    read : callable
        ``read(path: Path)``, the reader.
    what : str
        What the file is, for the messages (``"checkpoint"``, ``"mesh file"``).
    error : type, optional
        The exception raised (default :class:`~riskplan.errors.InvalidInputError`).
    hint : str
        Appended to the message about a missing file (``" (nothing to resume)"``).

    Returns
    -------
    object
        What ``read`` returns.

    Raises
    ------
    InvalidInputError
        (or ``error``) ``"{what} 'path': no such file"``, ``"... is a folder"`` or
        ``"... cannot read it (TypeName: message)"``.
    """
    from riskplan.errors import InvalidInputError

    error = InvalidInputError if error is None else error
    path = Path(path)
    if not path.is_file():
        why = "is a folder" if path.is_dir() else f"no such file{hint}"
        raise error(f"{what} {str(path)!r}: {why}")
    try:
        return read(path)
    except Exception as exc:  # a third-party reader's many types for unreadable files
        raise error(f"{what} {str(path)!r}: cannot read it ({type(exc).__name__}: {exc})") from exc


def canonical_json(obj) -> str:
    """Deterministic JSON text of ``obj`` (sorted keys, no spaces, non-finite numbers refused):
    the text content hashes are computed on.

    Parameters
    ----------
    obj : object
        JSON-serialisable data with finite numbers.

    Returns
    -------
    str
        The text.
    """
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)


def write_text_atomic(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (:func:`atomic_path`).

    Parameters
    ----------
    path : str or os.PathLike
        The file; its folder is created.
    text : str
        The content.
    """
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json_atomic(path, obj, **kwargs) -> None:
    """Write ``obj`` as JSON (indent 2 unless given, a final newline) to ``path`` atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The file; its folder is created.
    obj : object
        JSON-serialisable data.
    **kwargs
        Handed to ``json.dumps``.
    """
    kwargs.setdefault("indent", 2)
    write_text_atomic(path, json.dumps(obj, **kwargs) + "\n")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by someone else
        return True
    return True


@contextlib.contextmanager
def output_lock(path, what: str = "output"):
    """Hold ``<path>.lock`` while writing ``path``: a second writer gets a clear error.

    The lock file holds the owner's process id; a lock left by a process that no longer
    exists (killed) is taken over. Raises :class:`~riskplan.errors.OutputLockedError` (an
    ``InvalidInputError``) naming the running process otherwise.

    Parameters
    ----------
    path : str or os.PathLike
        The output being written.
    what : str
        What it is, for messages.

    Yields
    ------
    pathlib.Path
        The lock file.
    """
    from riskplan.errors import InvalidInputError, OutputLockedError

    path = Path(path)
    lock = path.with_name(path.name + ".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                pid = int(lock.read_text().strip() or 0)
            except (OSError, ValueError):
                pid = 0
            if pid and pid != os.getpid() and _pid_alive(pid):
                raise OutputLockedError(
                    f"{what} {str(path)!r} is being written by another process (pid {pid}, lock {lock.name}); "
                    "wait for it to finish or choose another output"
                ) from None
            lock.unlink(missing_ok=True)  # stale: its owner is gone
            continue
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{os.getpid()}\n")
        break
    else:  # pragma: no cover - lost two races in a row
        raise InvalidInputError(f"{what} {str(path)!r}: could not take the lock {lock.name}")
    try:
        yield lock
    finally:
        lock.unlink(missing_ok=True)
