"""`riskplan dataset generate` / `info`."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.datasets import load_dataset

runner = CliRunner()


def test_generate_both_splits_and_info(tmp_path):
    out = tmp_path / "d.h5"
    r = runner.invoke(
        app,
        [
            "dataset",
            "generate",
            "--preset",
            "tiny",
            "--out",
            str(out),
            "--backend",
            "serial",
            "--seed",
            "2",
        ],
    )
    assert r.exit_code == 0, r.output
    tr, te = tmp_path / "d_train.h5", tmp_path / "d_test.h5"
    assert load_dataset(tr).n_configs == 6 and load_dataset(te).n_configs == 2
    r = runner.invoke(app, ["dataset", "info", str(tr), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["configs_done"] == s["configs_total"] == 6 and s["robot"] == "paper" and s["seed"] == 2
    assert s["tip_spread_mm"]["max"] >= s["tip_spread_mm"]["mean"] > 0
    assert 0.0 <= s["arrivals_over_max_tension"] <= 1.0
    r = runner.invoke(app, ["dataset", "info", str(te)])
    assert r.exit_code == 0 and "configs_done" in r.output


def test_single_split_and_errors(tmp_path):
    out = tmp_path / "only.h5"
    r = runner.invoke(
        app,
        [
            "dataset",
            "generate",
            "--preset",
            "tiny",
            "--split",
            "test",
            "--out",
            str(out),
            "--backend",
            "serial",
        ],
    )
    assert r.exit_code == 0, r.output
    assert load_dataset(out).metadata["split"] == "test"
    r = runner.invoke(app, ["dataset", "generate", "--preset", "nope", "--out", str(out)])
    assert r.exit_code != 0
    bad = tmp_path / "bad.h5"
    bad.write_text("x")
    r = runner.invoke(app, ["dataset", "info", str(bad)])
    assert r.exit_code != 0


def test_split_paths_name_the_files_of_generate_splits():
    from pathlib import Path

    from riskplan.datasets import split_paths

    want = {"train": Path("a/d_train.h5"), "test": Path("a/d_test.h5")}
    assert split_paths("a/d.h5") == want and split_paths(Path("a/d")) == want
    assert split_paths("d.h5", ("test",)) == {"test": Path("d_test.h5")}
