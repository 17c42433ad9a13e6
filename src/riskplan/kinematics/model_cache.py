"""A learned model for any robot, built once and cached by the robot's content hash.

:func:`ensure_model` returns the MDN of a robot for a data-set preset: from the cache when a
finished build exists, else it builds one by the MDN paper's protocol (section III data set,
:func:`riskplan.datasets.generate_splits`; training, :func:`riskplan.kinematics.training.train`;
evaluation on the test split, :func:`riskplan.kinematics.evaluation.evaluate`) and caches it.

Cache location: ``$RISKPLAN_CACHE/models`` if ``RISKPLAN_CACHE`` is set, else
``$XDG_CACHE_HOME/riskplan/models`` (``~/.cache/riskplan/models``). One build lives in
``<robot hash>/<build hash>/``:

* ``<robot hash>``: SHA-256 of the robot's canonical parameters (:func:`robot_hash`: the
  parsed description, name left out, so the lab's task files of one robot share a model
  whatever their ``[problem]``);
* ``<build hash>``: the first 16 hex digits of the SHA-256 of the protocol (preset adapted to
  the robot), the training settings and the data seed;
* files: ``data_train.h5``, ``data_test.h5`` (and their ``.partial`` while generating),
  ``model/`` (``weights.pt``, ``model.json``, ``checkpoint.pt``), ``evaluation.json``, and
  ``build.json`` written last: a build without ``build.json`` is unfinished.

Resumable: a killed build continues where it stopped when called again with the same
arguments (data-set generation keeps finished configurations in ``.partial`` files, training
continues from its per-epoch checkpoint, a finished training is not repeated).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from riskplan._validation import check_count

log = logging.getLogger(__name__)

__all__ = ["ModelBuild", "build_key", "cache_root", "ensure_model", "robot_hash"]

BUILD_FILE = "build.json"
BUILD_FORMAT = "riskplan-model-build"
STAGES = ("dataset", "training", "evaluation")


def cache_root(cache=None) -> Path:
    """The model cache folder: ``cache`` if given, else ``$RISKPLAN_CACHE/models``, else
    ``$XDG_CACHE_HOME/riskplan/models`` (default ``~/.cache/riskplan/models``).

    Parameters
    ----------
    cache : str or pathlib.Path, optional
        An explicit folder.

    Returns
    -------
    pathlib.Path
        The folder (not created).
    """
    if cache is not None:
        return Path(cache)
    env = os.environ.get("RISKPLAN_CACHE")
    if env:
        return Path(env) / "models"
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "riskplan" / "models"


def robot_hash(robot) -> str:
    """SHA-256 (hex) of the robot's canonical parameters (name left out).

    Two files that describe the same robot (the lab's layouts, riskplan's own) hash alike.

    Parameters
    ----------
    robot : TendonRobot
        The robot.

    Returns
    -------
    str
        64 hex digits.
    """
    from riskplan.robots.params import params_to_dict

    d = params_to_dict(robot.params)
    d.pop("name", None)
    text = json.dumps(d, sort_keys=True, separators=(",", ":"), default=float)
    return hashlib.sha256(text.encode()).hexdigest()


def build_key(protocol, train_config, seed: int) -> str:
    """First 16 hex digits of the SHA-256 of the protocol JSON, the training settings and the seed.

    Parameters
    ----------
    protocol : Protocol
        The data-set protocol.
    train_config : TrainConfig
        The training settings.
    seed : int
        The build's seed.

    Returns
    -------
    str
        16 hex digits.
    """
    doc = {
        "protocol": json.loads(protocol.to_json()),
        "train": train_config.to_json(),
        "seed": seed,
    }
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass
class ModelBuild:
    """What :func:`ensure_model` returns: the model, where it lives, and how it was made.

    ``cached``: True when a finished build was found (nothing computed). ``timings``: seconds
    per stage of this call (``dataset``, ``training``, ``evaluation``; empty on a cache hit).
    ``evaluation``: the test-split figures (``Evaluation.to_json``).
    """

    model: object
    path: Path
    cached: bool
    timings: dict = field(default_factory=dict)
    evaluation: dict = field(default_factory=dict)
    record: dict = field(default_factory=dict)

    @property
    def box(self):
        """``(n, 2)`` box of the training data: the protocol's limits for the tendons and the
        retraction, the model's limits for a base rotation (an angle input, periodic, whose
        grid levels the protocol spreads over the full turn); the model's limits when the
        protocol has none."""
        import numpy as np

        lim = np.array(self.model.limits, dtype=np.float64)
        plim = self.record.get("protocol", {}).get("limits")
        if plim is None:
            return lim
        box = np.array(plim, dtype=np.float64)
        robot = self.model.robot
        if robot is not None and robot.base_motion.rotation:
            box[robot.n_tendons] = lim[robot.n_tendons]
        return np.clip(box, lim[:, :1], lim[:, 1:])


def _finished_model(model_dir: Path) -> bool:
    """Whether ``model_dir`` holds the final model of a training run (``"finished": true``)."""
    meta = model_dir / "model.json"
    try:
        return json.loads(meta.read_text(encoding="utf-8")).get("finished") is True
    except (OSError, ValueError):
        return False


def _default_train_config():
    from riskplan.kinematics.training import TrainConfig

    return TrainConfig()


def _train_stage(model_dir, train_path, cfg, say) -> None:
    """The training stage of :func:`ensure_model`: train into ``model_dir`` (resuming its
    checkpoint) unless a finished model is there; ``trained.json`` records the data's hash."""
    from riskplan.io import write_json_atomic
    from riskplan.kinematics.data import read_point_clouds
    from riskplan.kinematics.training import train

    trained = model_dir / "trained.json"
    if not trained.is_file() and _finished_model(model_dir):
        # killed after training saved its final model: nothing left to train
        write_json_atomic(trained, {"data_hash": read_point_clouds(train_path).content_hash})
    if not trained.is_file():
        data = read_point_clouds(train_path)
        resume = (model_dir / "checkpoint.pt").is_file()
        train(
            data,
            cfg,
            out=model_dir,
            resume=resume,
            overwrite=not resume,
            on_epoch=lambda rec: say("training", rec.epoch + 1, cfg.epochs),
        )
        write_json_atomic(trained, {"data_hash": data.content_hash})
    say("training", cfg.epochs, cfg.epochs)


def ensure_model(
    robot,
    *,
    preset: str = "small",
    cache=None,
    seed: int = 0,
    train_config=None,
    workers: int | None = 1,
    backend: str = "serial",
    progress=None,
) -> ModelBuild:
    """The cached MDN of ``robot`` for ``preset``, built (or finished) if needed.

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    preset : str
        Data-set preset (``tiny``, ``small``, ``paper``; adapted to the robot by
        :func:`~riskplan.datasets.protocol.protocol_for_robot`) or a protocol JSON.
    cache : str or pathlib.Path, optional
        Cache folder (default :func:`cache_root`).
    seed : int
        Seed of the data set and of training.
    train_config : TrainConfig, optional
        Training settings (default: their defaults, with ``seed``).
    workers, backend
        Data-set generation's parallel map (default: this process).
    progress : callable, optional
        ``progress(stage, done, total)``, ``stage`` one of ``STAGES`` (dataset, training,
        evaluation).

    Returns
    -------
    ModelBuild
        The model, its folder, whether it was cached, timings and the test-split figures.

    Raises :class:`InvalidInputError` for a bad preset before anything is written.
    """
    import dataclasses

    from riskplan.datasets import generate_splits
    from riskplan.datasets.protocol import protocol_for_robot, protocol_limits
    from riskplan.io import write_json_atomic
    from riskplan.kinematics.data import read_point_clouds
    from riskplan.kinematics.evaluation import evaluate
    from riskplan.kinematics.model_io import load_model

    check_count(seed, "seed", 0)
    protocol = protocol_for_robot(preset, robot)
    protocol_limits(protocol, robot)
    cfg = train_config or dataclasses.replace(_default_train_config(), seed=seed)
    cfg.validate()
    rh = robot_hash(robot)
    folder = cache_root(cache) / rh / build_key(protocol, cfg, seed)
    done_file = folder / BUILD_FILE
    model_dir = folder / "model"
    if done_file.is_file():
        record = json.loads(done_file.read_text(encoding="utf-8"))
        log.info("model cache hit: %s", folder)
        return ModelBuild(
            load_model(model_dir), folder, True, {}, record.get("evaluation", {}), record
        )
    folder.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda stage, done, total: None)
    timings = {}

    t = time.perf_counter()
    n_total = protocol.n_configs("train") + protocol.n_configs("test")
    offset = {"train": 0, "test": protocol.n_configs("train")}
    paths = {}
    for split in ("train", "test"):

        def gen_progress(done, total, split=split):
            say("dataset", offset[split] + done, n_total)

        paths.update(
            generate_splits(
                robot,
                protocol,
                folder / "data.h5",
                seed=seed,
                splits=(split,),
                workers=workers,
                backend=backend,
                progress=gen_progress,
            )
        )
    say("dataset", n_total, n_total)
    timings["dataset_s"] = time.perf_counter() - t

    t = time.perf_counter()
    _train_stage(model_dir, paths["train"], cfg, say)
    timings["training_s"] = time.perf_counter() - t

    t = time.perf_counter()
    say("evaluation", 0, 1)
    model = load_model(model_dir)
    ev = evaluate(model, read_point_clouds(paths["test"]), seed=seed).to_json()
    say("evaluation", 1, 1)
    timings["evaluation_s"] = time.perf_counter() - t
    record = {
        "format": BUILD_FORMAT,
        "robot_hash": rh,
        "robot_name": robot.name,
        "protocol": json.loads(protocol.to_json()),
        "train": cfg.to_json(),
        "seed": seed,
        "timings_s": timings,
        "evaluation": ev,
    }
    write_json_atomic(folder / "evaluation.json", ev)
    write_json_atomic(done_file, record)  # last: marks the build finished
    return ModelBuild(model, folder, False, timings, ev, record)
