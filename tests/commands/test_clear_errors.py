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
    (["robot", "shape", "-d", "0,0,0,0", "--plot", "{d}/a_file/p.png"], "existing file"),
    (["dataset", "generate", "--out", "{d}", "--split", "train", "--preset", "tiny"], "folder"),
    # parsing
    (["collision", "-d", "0,0,0,0;0,0"], "equal length"),
    (["collision", "--arc", "8,0", "-d", "0,0,0,0"], "either --arc"),
    (["collision", "--env", "{d}/a_file", "--arc", "8,0"], "mesh"),
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
    ["collision", "--arc", "8,0", "--samples", "0"],
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


@pytest.mark.parametrize("argv", USAGE)
def test_usage_errors(files, argv):
    res = runner.invoke(app, [a.format(d=files) for a in argv])
    assert res.exit_code == 2, res.output


def test_help_texts_keep_their_units_and_name_real_commands():
    import re

    for argv in (["robot", "shape", "--help"], ["predict", "--help"], ["collision", "--help"]):
        out = re.sub(r"\s+", " ", runner.invoke(app, argv, terminal_width=200).output)
        if argv[0] != "collision":
            assert "(m)" in out, argv  # "[m]" was swallowed as rich markup
        assert "kinematics train" not in out


def test_version():
    from riskplan import __version__

    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0 and res.output.strip() == f"riskplan {__version__}"
