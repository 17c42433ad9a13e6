"""Bad command lines end in a named error (or a usage error), never a traceback, and before any work."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.errors import RiskplanError

runner = CliRunner()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    (d / "a_file").write_text("x")
    from riskplan.kinematics.data import write_synthetic_dataset

    rng = np.random.default_rng(0)
    write_synthetic_dataset(
        d / "data.h5", rng.uniform(0, 0.01, (4, 2)), rng.normal(scale=0.01, size=(4, 1, 8, 3))
    )
    np.savez(d / "selected.npz", controls=np.zeros((5, 2)))
    whole = (d / "selected.npz").read_bytes()
    (d / "trunc.npz").write_bytes(whole[: len(whole) // 2])
    return d


CASES = [
    # an output path that is an existing file (or lies below one)
    (["train", "--data", "{d}/data.h5", "--out", "{d}/a_file"], "existing file"),
    (
        [
            "sweep",
            "--data",
            "{d}/data.h5",
            "--test",
            "{d}/data.h5",
            "--out",
            "{d}/a_file",
            "--components",
            "1",
        ],
        "existing file",
    ),
    (
        ["evaluate", "--model", "{d}/nothing", "--data", "{d}/data.h5", "--out", "{d}/a_file"],
        "existing file",
    ),
    (["demo", "--out", "{d}/a_file"], "existing file"),
    (["env", "chest", "--out", "{d}/a_file/chest.stl"], "existing file"),
    (["env", "chest", "--out", "{d}/c.xyz"], ".stl"),
    (["plan", "chest", "--out", "{d}/a_file"], "existing file"),
    (["plan", "tissue", "--out", "{d}/a_file"], "existing file"),
    (["reproduce", "--out", "{d}/a_file"], "existing file"),
    (["tissue", "simulate", "--out", "{d}/a_file"], "existing file"),
    (["plan", "tissue", "--out", "{d}/pt", "--method", "foo"], "--method"),
    (["tissue", "simulate", "--out", "{d}/ts", "--controls", "{d}/trunc.npz"], ".npz"),
    # work budgets: refused up front, naming the option
    (["plan", "chest", "--out", "{d}/pc", "--candidates", "1000000000"], "candidates"),
    (["plan", "chest", "--out", "{d}/pc", "--resolution", "1e-12"], "--resolution"),
    (["plan", "chest", "--out", "{d}/pc", "--step", "1e-12"], "--step"),
    (["plan", "chest", "--out", "{d}/pc", "--executions", "10000000000"], "--executions"),
    (["plan", "chest", "--out", "{d}/pc", "--milestones", "100000000"], "--milestones"),
    (["plan", "chest", "--out", "{d}/pc", "--iterations", "100000000"], "iterations"),
    (["tissue", "simulate", "--out", "{d}/ts", "--steps", "1000000000"], "--steps"),
    (["plan", "tissue", "--out", "{d}/pt", "--plans", "1000000000"], "--plans"),
    (["plan", "tissue", "--out", "{d}/pt", "--check-runs", "1000000000000"], "--check-runs"),
    (["robot", "shape", "-d", "0,0,0,0", "--plot", "{d}/a_file/p.png"], "existing file"),
    (["dataset", "generate", "--out", "{d}", "--split", "train", "--preset", "tiny"], "folder"),
    # parsing
    (["collision", "probability", "-d", "0,0,0,0;0,0"], "equal length"),
    (["collision", "probability", "--arc", "8,0", "-d", "0,0,0,0"], "either --arc"),
    (["collision", "probability", "--env", "{d}/a_file", "--arc", "8,0"], "mesh"),
]

USAGE = [  # rejected by the option parser itself (exit code 2), before anything runs
    ["train", "--data", "{d}/data.h5", "--out", "{d}/m", "--seed", "-1"],
    ["train", "--data", "{d}/data.h5", "--out", "{d}/m", "--patience", "-1"],
    [
        "sweep",
        "--data",
        "{d}/data.h5",
        "--test",
        "{d}/data.h5",
        "--out",
        "{d}/s",
        "--workers",
        "-1",
    ],
    ["dataset", "generate", "--out", "{d}/x.h5", "--workers", "-1"],
    ["demo", "--out", "{d}/demo", "--seed", "-3"],
    ["collision", "probability", "--arc", "8,0", "--samples", "0"],
    # --workers is one shared option (min 0) wherever a command runs a process pool
    ["plan", "tissue", "--out", "{d}/pt", "--workers", "-1"],
    ["reproduce", "--out", "{d}/rp", "--workers", "-1"],
    # seeds and counts: once tracebacks from NumPy, or errors after the planning had run
    ["plan", "chest", "--out", "{d}/pc", "--seed", "-1"],
    ["plan", "chest", "--out", "{d}/pc", "--chest-seed", "-1"],
    ["plan", "chest", "--out", "{d}/pc", "--workers", "-1"],
    ["plan", "chest", "--out", "{d}/pc", "--milestones", "0"],
    ["plan", "tissue", "--out", "{d}/pt", "--seed", "-1"],
    ["plan", "tissue", "--out", "{d}/pt", "--check-runs", "-1"],
    ["reproduce", "--out", "{d}/rp", "--seed", "-1"],
    [
        "evaluate",
        "--model",
        "paper",
        "--data",
        "{d}/data.h5",
        "--out",
        "{d}/e",
        "--max-configs",
        "-1",
    ],
    [
        "evaluate",
        "--model",
        "paper",
        "--data",
        "{d}/data.h5",
        "--out",
        "{d}/e",
        "--figure-configs",
        "-1",
    ],
    [
        "evaluate",
        "--model",
        "paper",
        "--data",
        "{d}/data.h5",
        "--out",
        "{d}/e",
        "--chamfer-points",
        "0",
    ],
]


@pytest.mark.parametrize("argv, match", CASES)
def test_named_errors(files, argv, match):
    res = runner.invoke(app, [a.format(d=files) for a in argv])
    assert res.exit_code != 0
    assert isinstance(res.exception, RiskplanError), repr(res.exception)
    assert match in str(res.exception)


@pytest.mark.parametrize("argv, match", CASES)
def test_named_errors_leave_no_output(files, argv, match):
    """Refused before any work: the output folder is not even created."""
    args = [a.format(d=files) for a in argv]
    if "--out" not in args:
        return
    from pathlib import Path

    out = Path(args[args.index("--out") + 1])
    if out.exists() or str(out).startswith(str(files / "a_file")):
        return  # the cases about an output that exists already
    runner.invoke(app, args)
    assert not out.exists()


LOCKED = [  # every command that writes a folder (or a mesh file) takes its lock
    ["train", "--data", "{d}/data.h5", "--out", "{o}"],
    [
        "sweep",
        "--data",
        "{d}/data.h5",
        "--test",
        "{d}/data.h5",
        "--out",
        "{o}",
        "--components",
        "1",
    ],
    ["evaluate", "--model", "paper", "--data", "{d}/data.h5", "--out", "{o}"],
    ["plan", "chest", "--out", "{o}"],
    ["plan", "tissue", "--out", "{o}"],
    ["tissue", "simulate", "--out", "{o}"],
    ["env", "chest", "--out", "{o}.stl"],
    ["demo", "--out", "{o}"],
    ["reproduce", "--out", "{o}"],
]


@pytest.mark.parametrize("argv", LOCKED, ids=lambda a: " ".join(a[:2]))
def test_a_second_writer_is_refused(files, tmp_path, argv):
    """Another live process holds the output's lock: the command stops with
    OutputLockedError before writing anything (two `train` runs into one --out both exited 0
    and one model was lost)."""
    import os

    from riskplan.errors import OutputLockedError

    o = tmp_path / "out"
    args = [a.format(d=files, o=o) for a in argv]
    target = args[args.index("--out") + 1]
    lock = tmp_path / (os.path.basename(target) + ".lock")
    lock.write_text(f"{os.getppid()}\n")  # a live process that is not this one
    res = runner.invoke(app, args)
    assert isinstance(res.exception, OutputLockedError), repr(res.exception)
    assert f"pid {os.getppid()}" in str(res.exception)
    assert lock.read_text() == f"{os.getppid()}\n"  # the other writer's lock is untouched
    assert not any(o.iterdir()) if o.is_dir() else True


@pytest.mark.parametrize("argv", USAGE)
def test_usage_errors(files, argv):
    res = runner.invoke(app, [a.format(d=files) for a in argv])
    assert res.exit_code == 2, res.output


def test_help_texts_keep_their_units_and_name_real_commands():
    import re

    for argv in (
        ["robot", "shape", "--help"],
        ["predict", "--help"],
        ["collision", "probability", "--help"],
    ):
        out = re.sub(r"\s+", " ", runner.invoke(app, argv, terminal_width=200).output)
        if argv[0] != "collision":
            assert "(m)" in out, argv  # "[m]" was swallowed as rich markup
        assert "kinematics train" not in out


def test_version():
    from riskplan import __version__

    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0 and res.output.strip() == f"riskplan {__version__}"


def test_budget_can_be_raised(monkeypatch):
    """The ceilings are the user's: --max-memory / --max-hours (or the environment) let
    through what the defaults refuse."""
    from riskplan import budget
    from riskplan.errors import BudgetError

    monkeypatch.delenv(budget.MEMORY_ENV, raising=False)
    monkeypatch.delenv(budget.TIME_ENV, raising=False)
    with pytest.raises(BudgetError, match="--max-memory"):
        budget.check_budget("a request", "--x", nbytes=100 * 2**30)
    with pytest.raises(BudgetError, match="--max-hours"):
        budget.check_budget("a request", "--x", seconds=48 * 3600)
    monkeypatch.setenv(budget.MEMORY_ENV, "1")  # registered for restoring; the CLI sets it
    monkeypatch.setenv(budget.TIME_ENV, "1")
    res = runner.invoke(app, ["--max-memory", "1T", "--max-hours", "72", "robot", "info"])
    assert res.exit_code == 0, res.output
    budget.check_budget("a request", "--x", nbytes=100 * 2**30, seconds=48 * 3600)
    res = runner.invoke(app, ["--max-memory", "lots", "robot", "info"])
    assert "--max-memory" in str(res.exception)
