"""`riskplan tissue simulate` end to end (small runs) and the controls file formats."""

from __future__ import annotations

import json

import numpy as np
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


def test_read_controls_formats(tmp_path, tol):
    a = tmp_path / "a.json"
    a.write_text("[[0.1, 0.2], [0.3, 0.4]]")
    np.testing.assert_allclose(
        read_controls(a, 2), [[0.1, 0.2], [0.3, 0.4]], **tol["float64_exact"]
    )
    b = tmp_path / "b.txt"
    b.write_text("0.1,0.2\n\n0.3,0.4\n")
    np.testing.assert_allclose(
        read_controls(b, 2), [[0.1, 0.2], [0.3, 0.4]], **tol["float64_exact"]
    )
    bad = tmp_path / "c.csv"
    bad.write_text("0.1,0.2\n0.3\n")
    with pytest.raises(DataFormatError):
        read_controls(bad, 2)
    bad.write_text("0.1,0.2,0.3\n")
    with pytest.raises(InvalidInputError):
        read_controls(bad, 2)
    bad.write_text("0.1,nan\n")
    with pytest.raises(InvalidInputError):
        read_controls(bad, 2)
    with pytest.raises(DataFormatError):
        read_controls(tmp_path / "missing.csv", 2)
    j = tmp_path / "d.json"
    j.write_text("{not json")
    with pytest.raises(DataFormatError):
        read_controls(j, 2)


def test_read_controls_npz(tmp_path, tol):
    # the selected.npz of `riskplan plan tissue` replays; a file of several plans is refused
    u = np.array([[0.1, 0.2], [0.3, -0.4], [0.5, 0.0]])
    one = tmp_path / "selected.npz"
    np.savez(one, controls=u, reduced=np.zeros((4, 3)))
    np.testing.assert_allclose(read_controls(one, 2), u, **tol["float64_exact"])
    several = tmp_path / "candidates.npz"
    np.savez(several, controls=u, control_offsets=np.array([0, 1, 3]))
    with pytest.raises(DataFormatError, match="several plans"):
        read_controls(several, 2)
    other = tmp_path / "other.npz"
    np.savez(other, forces=u)
    with pytest.raises(DataFormatError, match="no 'controls' array"):
        read_controls(other, 2)
    fake = tmp_path / "fake.npz"
    fake.write_text("not a zip")
    with pytest.raises(DataFormatError, match=r"fake\.npz"):
        read_controls(fake, 2)


def test_step_cost_keys():
    from riskplan.bench.tissue import step_costs

    out = step_costs(quick=True)
    for n in (175, 1000):
        for key in (
            f"needle_step_us_{n}",
            f"needle_step_and_collision_us_{n}",
            f"manipulation_step_ms_{n}",
            f"manipulation_reduced_us_{n}",
        ):
            assert out[key] > 0


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


def test_manipulation_random_controls_bad_count():
    from riskplan.scenarios.manipulation import ManipulationScenario

    with pytest.raises(InvalidInputError, match="n_steps"):
        ManipulationScenario().random_controls(-1, seed=0)
    assert ManipulationScenario().random_controls(0, seed=0).shape == (0, 6)
