"""``riskplan reproduce`` continues from any kill: a run killed with SIGKILL (no cleanup) at a
stage boundary or inside a long stage, then rerun with the same command, finishes, and its
``results.json`` equals an uninterrupted run's (wall-clock measurements aside: MDN training
is bounded by epochs here, so everything else is deterministic).

The driver is :mod:`tests.app.kill_rerun` (a subprocess that kills itself where told).
``make test`` runs one kill, inside MDN training (the stage that could not be continued); the
full matrix, every stage boundary and inside every long stage of both papers (20 kills, each
a killed run and its rerun of a few seconds of work plus process start-up; 10 to 50 minutes
on two shared cores, by load), is marked ``kill_matrix`` and runs with::

    RISKPLAN_KILL_MATRIX=1 python -m pytest -m kill_matrix tests/app/test_reproduce_kills.py
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.app.kill_rerun import deterministic

ROOT = Path(__file__).resolve().parents[2]

#: (paper, where, n): where the run is killed (see the driver's docstring)
FULL = [
    # deformable: each stage's boundary and inside the long ones, both scenarios
    ("deformable", "needle: RRT candidates", 1),
    ("deformable", "needle: RRT candidates", 2),
    ("deformable", "needle: linearise + LQG-MP", 1),
    ("deformable", "needle: linearise + LQG-MP", 2),
    ("deformable", "needle: executions", 1),
    ("deformable", "needle: executions", 3),
    ("deformable", "manipulation: RRT candidates", 1),
    ("deformable", "manipulation: linearise + LQG-MP", 2),
    ("deformable", "manipulation: executions", 3),
    ("deformable", "@report", 1),
    # MDN: data set, training, sweep, timing, Fig. 7, report
    ("mdn", "mdn: data set", 1),
    ("mdn", "@data", 3),
    ("mdn", "mdn: train", 1),
    ("mdn", "@train", 2),
    ("mdn", "mdn: K sweep", 1),
    ("mdn", "@train", 5),  # inside the sweep's first model
    ("mdn", "mdn: timing", 1),
    ("mdn", "mdn: Fig. 7", 1),
    ("mdn", "mdn: Fig. 7", 2),
    ("mdn", "@report", 1),
]
#: the subset in ``make test``: killed after the second epoch of MDN training
SUBSET = [("mdn", "@train", 2)]


def _run(out: Path, paper: str, *kill) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT)])}
    return subprocess.run(
        [sys.executable, "-m", "tests.app.kill_rerun", str(out), paper, *map(str, kill)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )


def _results(out: Path) -> dict:
    return deterministic(json.loads((out / "results.json").read_text()))


@pytest.fixture(scope="module")
def references(tmp_path_factory):
    cache: dict = {}

    def get(paper: str) -> dict:
        if paper not in cache:
            out = tmp_path_factory.mktemp(f"ref-{paper}")
            done = _run(out, paper)
            assert done.returncode == 0, done.stderr[-3000:]
            cache[paper] = _results(out)
        return cache[paper]

    return get


def _kill_and_rerun(references, tmp_path, paper, where, n):
    out = tmp_path / "out"
    killed = _run(out, paper, where, n)
    assert killed.returncode == -signal.SIGKILL, (killed.returncode, killed.stderr[-3000:])
    assert not (out / "report.html").exists()
    rerun = _run(out, paper)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert _results(out) == references(paper)


@pytest.mark.parametrize("paper, where, n", SUBSET)
def test_killed_during_training_continues_to_the_same_results(
    references, tmp_path, paper, where, n
):
    _kill_and_rerun(references, tmp_path, paper, where, n)


@pytest.mark.kill_matrix
@pytest.mark.skipif(
    not os.environ.get("RISKPLAN_KILL_MATRIX"), reason="set RISKPLAN_KILL_MATRIX=1 (10-50 min)"
)
@pytest.mark.parametrize("paper, where, n", FULL, ids=lambda v: str(v).replace(" ", "_"))
def test_kill_matrix(references, tmp_path, paper, where, n):
    _kill_and_rerun(references, tmp_path, paper, where, n)
