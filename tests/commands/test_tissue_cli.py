"""`riskplan tissue simulate` end to end (small runs), with its input checks."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.scenarios.controls import read_controls

runner = CliRunner()


def test_simulate_needle_from_csv(tmp_path):
    ctrl = tmp_path / "u.csv"
    ctrl.write_text("# speed, steering\nv,phi\n0.5,0.0\n0.5,0.3\n0.4,-0.2\n")
    out = tmp_path / "out"
    r = runner.invoke(
        app,
        [
            "tissue",
            "simulate",
            "--scenario",
            "needle",
            "--controls",
            str(ctrl),
            "--out",
            str(out),
            "--case",
            "material-high",
            "--seed",
            "2",
        ],
    )
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == 3 and summary["case"] == "material-high"
    assert summary["params"]["youngs_modulus"] != 50.0
    assert (out / "needle.gif").is_file() and len(list((out / "frames").glob("*.png"))) == 4


def test_simulate_needle_that_leaves_the_tissue_fails_with_that_reason(tmp_path):
    """Straight on from x = 0.05 for 30 steps of 0.04: the needle leaves the unit square
    (x > 1) at step 24; the summary says so instead of reporting no failure."""
    ctrl = tmp_path / "u.csv"
    ctrl.write_text("v,phi\n" + "0.4,0.0\n" * 30)
    out = tmp_path / "out"
    args = ["tissue", "simulate", "--scenario", "needle", "--controls", str(ctrl)]
    r = runner.invoke(app, [*args, "--out", str(out), "--max-frames", "2"])
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "summary.json").read_text())
    # material x after k steps: 0.05 + 0.04 k, above 1 first at k = 24 (0.97 at 23)
    assert summary["left_tissue_step"] == 24
    assert summary["outcome"] == "left_tissue" and "left the tissue at step 24" in summary["reason"]
    assert "FAILED" in r.output


def test_simulate_manipulation_random_json(tmp_path):
    out = tmp_path / "m"
    r = runner.invoke(
        app,
        [
            "tissue",
            "simulate",
            "--scenario",
            "manipulation",
            "--controls",
            "random",
            "--out",
            str(out),
            "--steps",
            "3",
            "--max-frames",
            "2",
        ],
    )
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["final_reduced_state"]) == 32 and summary["steps"] == 3


def test_simulate_rejects_bad_input(tmp_path):
    ctrl = tmp_path / "u.json"
    ctrl.write_text(json.dumps({"controls": [[0.9, 0.0]]}))  # speed above v_max
    r = runner.invoke(
        app, ["tissue", "simulate", "--controls", str(ctrl), "--out", str(tmp_path / "o")]
    )
    assert r.exit_code != 0
    r = runner.invoke(
        app, ["tissue", "simulate", "--scenario", "liver", "--out", str(tmp_path / "o")]
    )
    assert r.exit_code != 0
    r = runner.invoke(app, ["tissue", "simulate", "--case", "bogus", "--out", str(tmp_path / "o")])
    assert r.exit_code != 0


def test_controls_validated_before_any_simulation(tmp_path):
    # row 49 of 60 out of bounds: named, and nothing simulated or written (it used to fail at step 49)
    rows = [[0.5, 0.0]] * 60
    rows[48] = [0.5, 9.0]
    ctrl = tmp_path / "u.json"
    ctrl.write_text(json.dumps(rows))
    out = tmp_path / "o"
    r = runner.invoke(app, ["tissue", "simulate", "--controls", str(ctrl), "--out", str(out)])
    assert r.exit_code != 0 and "row 49 column 2" in str(r.exception) and not out.exists()
    # --max-frames 0 used to fail after the whole simulation, leaving an empty frames/
    r = runner.invoke(
        app, ["tissue", "simulate", "--steps", "2", "--max-frames", "0", "--out", str(out)]
    )
    assert r.exit_code != 0 and "--max-frames" in str(r.exception) and not out.exists()
    latin = tmp_path / "latin.csv"
    latin.write_bytes("# d\xe9placement\n0.5,0.0\n".encode("latin-1"))
    with pytest.raises(DataFormatError, match="UTF-8"):
        read_controls(latin, 2)
    afile = tmp_path / "file"
    afile.write_text("x")
    r = runner.invoke(app, ["tissue", "simulate", "--steps", "2", "--out", str(afile)])
    assert isinstance(r.exception, InvalidInputError) and "existing file" in str(r.exception)
    r = runner.invoke(
        app, ["tissue", "simulate", "--steps", "2", "--seed", "-1", "--out", str(out)]
    )
    assert isinstance(r.exception, InvalidInputError) and "--seed" in str(r.exception)
