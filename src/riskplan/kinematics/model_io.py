"""Saving and loading trained MDN models: ``weights.pt`` + ``model.json`` in a folder.

``weights.pt`` is a torch ``state_dict`` (loaded with ``weights_only=True``, no pickled
code). ``model.json`` holds everything else: format and versions, architecture,
input/output normalisation, the robot (TOML text, name, tendon count, displacement
limits), the data set's content hash, training options and history, and the SHA-256
of ``weights.pt``. Both files are written atomically, weights first; the hash in the
JSON detects a weights file that does not belong to it (torn or corrupted writes).

Shipped models: riskplan carries trained models under ``riskplan/data/models/<name>/`` in
the same format (``shipped_models()`` lists them). :func:`load_model` takes a folder path or,
when no folder of that name exists, a shipped name such as ``"paper"`` (the MDN trained on
the ``paper`` data-set preset; its ``model.json`` ``provenance`` entry names the data set,
its content hash, the commands and the test NLL). Shipped models are hash-checked like any other.
"""

from __future__ import annotations

import hashlib
import io
import itertools
import json
import logging
import platform
from pathlib import Path

import numpy as np
import torch

from riskplan._validation import check_count
from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.io import atomic_path, write_json_atomic
from riskplan.kinematics.mdn import MDN, MDNModel, Normalisation

log = logging.getLogger(__name__)

FORMAT = "riskplan-mdn"
FORMAT_VERSION = 1
WEIGHTS_NAME = "weights.pt"
META_NAME = "model.json"
# keys written by save_model itself (a loaded model's metadata keeps only the others)
_RESERVED = frozenset(
    (
        "format",
        "format_version",
        "versions",
        "architecture",
        "normalisation",
        "robot",
        "weights_file",
        "weights_sha256",
    )
)


def _versions() -> dict:
    import riskplan

    return {
        "riskplan": riskplan.__version__,
        "torch": torch.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }


def save_model(model: MDNModel, path) -> Path:
    """Write ``path/weights.pt`` and ``path/model.json``, atomically.

    Parameters
    ----------
    model : MDNModel
        The trained model (network, normalisation, robot description, metadata).
    path : str or path
        The model folder (created if missing).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    torch.save(model.net.state_dict(), buf)
    blob = buf.getvalue()
    with atomic_path(path / WEIGHTS_NAME, suffix=".pt") as tmp:
        tmp.write_bytes(blob)
    p = next(model.net.parameters())
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "versions": _versions(),
        "architecture": {**model.net.architecture(), "dtype": str(p.dtype).removeprefix("torch.")},
        "normalisation": model.normalisation.to_json(),
        "robot": {
            "name": model.robot_name,
            "n_tendons": model.n_tendons,
            "displacement_limits": np.asarray(model.limits, dtype=np.float64).tolist(),
            "toml": model.robot_toml,
        },
        "weights_file": WEIGHTS_NAME,
        "weights_sha256": hashlib.sha256(blob).hexdigest(),
        **{k: v for k, v in model.metadata.items() if k not in _RESERVED},
    }
    write_json_atomic(path / META_NAME, meta)
    for name in (WEIGHTS_NAME, META_NAME):
        _usual_permissions(path / name)
    return path


def _usual_permissions(path: Path) -> None:
    """Atomic writes go through ``mkstemp`` (mode 0600); give the file the usual ``0666 & ~umask``."""
    import os

    mask = os.umask(0)
    os.umask(mask)
    os.chmod(path, 0o666 & ~mask)


def _shipped_root() -> Path:
    from importlib.resources import files

    return Path(str(files("riskplan") / "data" / "models"))


def shipped_models() -> tuple[str, ...]:
    """Names of the models shipped with riskplan (folders under ``riskplan/data/models``).

    Returns
    -------
    tuple of str
        Sorted names, each loadable by :func:`~riskplan.kinematics.load_model`.
    """
    root = _shipped_root()
    if not root.is_dir():
        return ()
    return tuple(sorted(p.name for p in root.iterdir() if (p / META_NAME).is_file()))


def resolve_model(name_or_path) -> Path:
    """The model folder for a path or a shipped model name.

    An existing folder (or its ``model.json`` / ``weights.pt``) wins; otherwise a name from
    :func:`shipped_models` resolves to its packaged folder.

    Parameters
    ----------
    name_or_path : str or os.PathLike
        Folder, file in it, or shipped name.

    Returns
    -------
    pathlib.Path
        The folder.

    Raises
    ------
    DataFormatError
        Neither a folder nor a shipped name (the message lists the shipped names).
    """
    if not isinstance(name_or_path, (str, Path)):
        raise InvalidInputError(
            f"model: expected a folder path or a shipped model name, got {type(name_or_path).__name__}"
        )
    path = Path(name_or_path)
    if path.is_file() and path.name in (META_NAME, WEIGHTS_NAME):
        return path.parent
    if path.is_dir():
        return path
    name = str(name_or_path)
    if name in shipped_models():
        return _shipped_root() / name
    raise DataFormatError(
        f"model {name!r}: not a model folder (no {META_NAME} there) and not a shipped model name "
        f"(shipped: {', '.join(repr(n) for n in shipped_models()) or 'none'})"
    )


def load_model(path, robot=None) -> MDNModel:
    """Load a model folder written by :func:`save_model`, or a shipped model by name.

    Parameters
    ----------
    path : str or os.PathLike
        A model folder, its ``model.json``, or a name from :func:`shipped_models`
        (``"paper"``; used only when no folder of that name exists).
    robot : TendonRobot, optional
        The robot (anything with ``toml_text()``) the model must belong to.

    Returns
    -------
    MDNModel
        The model, its weights checked against the metadata's SHA-256.

    Raises
    ------
    DataFormatError
        An unknown name (listing the shipped ones), missing files, corrupted JSON or
        weights, weights that do not match the metadata, or a model of another robot.
    """
    path = resolve_model(path)
    meta_path = path / META_NAME
    if not meta_path.is_file():
        raise DataFormatError(f"model {str(path)!r}: no {META_NAME} (not a model folder)")
    try:
        meta = json.loads(meta_path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(f"model {str(path)!r}: {META_NAME} is corrupted ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise DataFormatError(
            f"model {str(path)!r}: {META_NAME} has format={meta.get('format') if isinstance(meta, dict) else None!r}, expected {FORMAT!r}"
        )
    if meta.get("format_version") != FORMAT_VERSION:
        raise DataFormatError(
            f"model {str(path)!r}: format_version={meta.get('format_version')!r} is not supported (expected {FORMAT_VERSION})"
        )
    try:
        arch = meta["architecture"]
        norm = Normalisation.from_json(meta["normalisation"])
        rob = meta["robot"]
        limits = np.asarray(rob["displacement_limits"], dtype=np.float64)
        weights_file = path / meta.get("weights_file", WEIGHTS_NAME)
        expected_hash = meta["weights_sha256"]
    except (KeyError, TypeError, ValueError) as exc:
        raise DataFormatError(
            f"model {str(path)!r}: {META_NAME} lacks or has a malformed entry ({type(exc).__name__}: {exc})"
        ) from exc
    if not weights_file.is_file():
        raise DataFormatError(f"model {str(path)!r}: weights file {weights_file.name!r} is missing")
    blob = weights_file.read_bytes()
    got = hashlib.sha256(blob).hexdigest()
    if got != expected_hash:
        raise DataFormatError(
            f"model {str(path)!r}: {weights_file.name} does not match {META_NAME} (SHA-256 {got[:12]}... != {expected_hash[:12]}...); "
            "the file is corrupted or from another model"
        )
    _check_architecture(path, arch)
    try:
        state = torch.load(io.BytesIO(blob), map_location="cpu", weights_only=True)
        net = MDN(
            int(arch["n_inputs"]),
            int(arch["n_components"]),
            int(arch.get("dim", 3)),
            tuple(arch["hidden"]),
            tuple(arch["head_hidden"]),
            arch.get("activation", "silu"),
            tuple(arch.get("angle_inputs", ())),
        )
        net = net.to(getattr(torch, arch.get("dtype", "float32")))
        net.load_state_dict(state)
    except (
        InvalidInputError,
        KeyError,
        TypeError,
        RuntimeError,
        ValueError,
        AttributeError,
    ) as exc:
        raise DataFormatError(
            f"model {str(path)!r}: weights do not fit the architecture in {META_NAME} ({type(exc).__name__}: {exc})"
        ) from exc
    m = net.n_inputs
    if limits.shape != (m, 2) or norm.input_mean.shape != (m,) or norm.output_scale.shape != (3,):
        raise DataFormatError(
            f"model {str(path)!r}: metadata shapes disagree with {m} tendons (limits {limits.shape}, input_mean {norm.input_mean.shape})"
        )
    _check_numbers(path, net, norm, limits)
    extra = {k: v for k, v in meta.items() if k not in _RESERVED}
    if extra.get("finished") is False:
        log.warning(
            "model %s is unfinished: saved during a training run that has not ended (best epoch %s); "
            "resume it with `riskplan model train --resume`",
            path,
            extra.get("best_epoch"),
        )
    model = MDNModel(net, norm, limits, rob.get("toml", ""), rob.get("name", ""), extra)
    if robot is not None:
        check_robot(model, robot)
    return model


# Bounds on what a model file may ask for (a corrupted or hostile model.json must not make the
# loader allocate gigabytes): far above any MDN of the paper's kind (2 x 64 hidden units, K <= 10).
MAX_TENDONS = 64
MAX_COMPONENTS = 1024
MAX_LAYERS = 32
MAX_WIDTH = 65536
MAX_PARAMETERS = 50_000_000


def _check_architecture(path: Path, arch) -> None:
    """Raise :class:`DataFormatError` unless ``arch`` names a network of sensible size."""
    where = f"model {str(path)!r}: {META_NAME} architecture"
    if not isinstance(arch, dict):
        raise DataFormatError(f"{where}: expected an object, got {type(arch).__name__}")

    def count(key, low, high, default=None):
        return check_count(
            arch.get(key, default), f"{where}: {key}", low, maximum=high, error=DataFormatError
        )

    def widths(key):
        v = arch.get(key)
        if not isinstance(v, (list, tuple)) or len(v) > MAX_LAYERS:
            raise DataFormatError(
                f"{where}: {key} must be a list of at most {MAX_LAYERS} layer widths, got {v!r}"
            )
        for h in v:
            check_count(h, f"{where}: {key} width", 1, maximum=MAX_WIDTH, error=DataFormatError)
        return list(v)

    m = count("n_inputs", 1, MAX_TENDONS)
    k = count("n_components", 1, MAX_COMPONENTS)
    d = count("dim", 3, 3, 3)
    hidden, heads = widths("hidden"), widths("head_hidden")
    if not hidden:
        raise DataFormatError(f"{where}: hidden must name at least one layer")
    sizes = [m, *hidden]
    n = sum((a + 1) * b for a, b in itertools.pairwise(sizes))
    for out in (k, k * d, k * d * (d + 1) // 2):
        hs = [hidden[-1], *heads, out]
        n += sum((a + 1) * b for a, b in itertools.pairwise(hs))
    if n > MAX_PARAMETERS:
        raise DataFormatError(f"{where}: {n} parameters exceed the limit of {MAX_PARAMETERS}")
    if arch.get("dtype", "float32") not in ("float32", "float64"):
        raise DataFormatError(
            f"{where}: dtype must be 'float32' or 'float64', got {arch.get('dtype')!r}"
        )


def _check_numbers(path: Path, net, norm, limits: np.ndarray) -> None:
    """Every number read from a model must be finite, scales positive, limits ordered.

    A zero or NaN ``output_scale`` would otherwise turn every prediction into NaN with no error.
    """
    where = f"model {str(path)!r}"
    for name, t in net.state_dict().items():
        if t.is_floating_point() and not torch.isfinite(t).all():
            raise DataFormatError(f"{where}: weights {name!r} contain NaN or inf (corrupted model)")
    for key in ("input_mean", "input_scale", "output_centre", "output_scale"):
        v = getattr(norm, key)
        if not np.all(np.isfinite(v)):
            raise DataFormatError(
                f"{where}: {META_NAME} normalisation.{key} contains NaN or inf: {v.tolist()}"
            )
        if key.endswith("_scale") and not np.all(v > 0):
            raise DataFormatError(
                f"{where}: {META_NAME} normalisation.{key} must be > 0, got {v.tolist()}"
            )
    if not np.all(np.isfinite(limits)) or not np.all(limits[:, 0] < limits[:, 1]):
        raise DataFormatError(
            f"{where}: {META_NAME} robot.displacement_limits must be finite with low < high, got {limits.tolist()}"
        )


def check_robot(model: MDNModel, robot) -> None:
    """Raise :class:`DataFormatError` if ``robot`` is not the robot ``model`` was trained for."""
    from riskplan.kinematics.data import _normalise_toml

    m = int(getattr(robot, "n_tendons", model.n_tendons))
    name = getattr(robot, "name", "?")
    if m != model.n_tendons:
        raise DataFormatError(
            f"model was trained for robot {model.robot_name!r} with {model.n_tendons} tendons; robot {name!r} has {m}"
        )
    toml = robot.toml_text() if hasattr(robot, "toml_text") else str(robot)
    if _normalise_toml(toml) != _normalise_toml(model.robot_toml):
        raise DataFormatError(
            f"model was trained for robot {model.robot_name!r}; robot {name!r} has a different description (robot TOML differs)"
        )
