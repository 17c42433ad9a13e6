"""Driver of the kill-and-rerun tests of ``riskplan reproduce`` (run as a subprocess).

``python -m tests.app.kill_rerun OUT PAPER [WHERE N]``: run the reproduction of
``PAPER`` at :data:`SCALES` (every stage, a few seconds each; MDN training bounded by epochs,
not wall-clock, so two uninterrupted runs agree) into ``OUT``. With ``WHERE N`` the process
kills itself with SIGKILL (no cleanup, no ``finally``):

* ``WHERE`` a stage name prefix (``"needle: executions"``, ``"mdn: train"``): at the ``N``-th
  progress report of that stage (``N = 1``: at the stage boundary, before its work; more:
  inside the stage, after some of its work was stored);
* ``@data``: after the ``N``-th simulated target of the MDN data sets;
* ``@train``: after the ``N``-th training checkpoint written (epochs of the Fig. 5 model,
  then of the K sweep's models);
* ``@report``: when the report starts (``results.json`` written, the report not).
"""

from __future__ import annotations

import os
import signal
import sys

from riskplan.app.reproduce.deformable import ScenarioScale
from riskplan.app.reproduce.mdn import MDNScale

#: the smallest reproduction that runs every stage (epoch-bounded training: deterministic);
#: manipulation with 4 draws for M_t, as the smoke scale (with 2 LQG-MP meets a singular
#: covariance on this plan)
SCALES = {
    "needle": ScenarioScale(
        n_candidates=1,
        n_executions=2,
        batch_size=1,
        lin_samples=2,
        goal_samples=50,
        plans_per_tree=1,
    ),
    "manipulation": ScenarioScale(
        n_candidates=1,
        n_executions=2,
        batch_size=1,
        lin_samples=4,
        goal_samples=50,
        plans_per_tree=1,
    ),
    "mdn": MDNScale(
        preset="tiny",
        components=(1, 2),
        n_components=2,
        epochs=3,
        sweep_epochs=2,
        train_seconds=0.0,
        sweep_seconds=0.0,
        timing_configs=4,
        bo_iterations=2,
        bo_candidates=16,
        milestones=40,
    ),
}

#: results.json keys that hold wall-clock measurements (differ between any two runs)
WALL_CLOCK = ("timing", "seconds")


def deterministic(obj):
    """``obj`` without its wall-clock measurements (:data:`WALL_CLOCK` keys, ``*_s`` keys)."""
    if isinstance(obj, dict):
        return {
            k: deterministic(v)
            for k, v in obj.items()
            if k not in WALL_CLOCK and not k.endswith("_s")
        }
    if isinstance(obj, list):
        return [deterministic(v) for v in obj]
    return obj


def main(argv: list[str]) -> None:
    from riskplan.app.reproduce.pipeline import reproduce

    out, paper = argv[0], argv[1]
    where, n = (argv[2], int(argv[3])) if len(argv) > 3 else (None, 0)
    seen = [0]

    def count() -> None:
        seen[0] += 1
        if seen[0] >= n:
            os.kill(os.getpid(), signal.SIGKILL)

    def progress(name: str, done: int, total: int) -> None:
        if where is not None and not where.startswith("@") and name.startswith(where):
            count()

    def after(module, name: str):
        original = getattr(module, name)

        def wrapped(*args, **kwargs):
            result = original(*args, **kwargs)
            count()
            return result

        setattr(module, name, wrapped)

    if where == "@data":
        from riskplan.datasets import generate

        after(generate, "_task")
    elif where == "@train":
        from riskplan.kinematics import training

        after(training, "save_checkpoint")
    elif where == "@report":
        from riskplan.app.reproduce import report as reproduce_report

        def killed(*args, **kwargs):
            os.kill(os.getpid(), signal.SIGKILL)

        reproduce_report.write_report = killed

    reproduce(out, paper=paper, scale=SCALES, backend="serial", seed=0, progress=progress)


if __name__ == "__main__":
    main(sys.argv[1:])
