"""``riskplan reproduce``'s MDN Fig. 7 stage at a smoke size (three Bayesian optimisation
iterations): its numbers are probabilities that agree with an independent evaluation of eq. 9
and eq. 10 on the stored trajectories, a rerun reads the stored record and gives identical
results, a corrupted record is refused with its file named, the paper's claim is computed from
the numbers, and the report shows the panel."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from riskplan.app.reproduce.mdn import MDNScale, fig7_claims, run_fig7
from riskplan.app.reproduce.paper_values import MDN
from riskplan.app.store import ResultStore
from riskplan.errors import DataFormatError, InvalidInputError

SMALL = MDNScale(bo_iterations=3)
CONFIG = {"test": "fig7", "seed": 0}


@pytest.fixture(scope="module")
def fig7(tmp_path_factory):
    root = tmp_path_factory.mktemp("fig7")
    calls = []
    r = run_fig7(
        root / "mdn",
        SMALL,
        ResultStore(root / "store", CONFIG),
        seed=0,
        progress=lambda s, d, n: calls.append((s, d, n)),
    )
    return root, r, calls


def test_values_present_and_probabilities(fig7, tol):
    from riskplan.collision import trajectory_probability

    root, r, calls = fig7
    tr = np.asarray(r["trace"])
    assert len(tr) == SMALL.bo_iterations + 1 == r["claims"]["iterations"] + 1
    assert np.all((tr >= 0) & (tr <= 1))
    assert np.all(np.diff(tr) <= 0)  # best bound so far: never rises
    for name in ("nominal", "optimised"):
        t = r[name]
        b = np.asarray(t["bounds_eq9"])
        assert len(b) == len(t["configurations"]) and np.all((b >= 0) & (b <= 1))
        # eq. 10 from the stored eq. 9 values, independently combined
        np.testing.assert_allclose(
            t["bound_eq10"], trajectory_probability(b), **tol["float64_exact"]
        )
    assert r["nominal"]["bound_eq10"] == tr[0] and r["optimised"]["bound_eq10"] == tr[-1]
    # start and goal never move
    for end in (0, -1):
        assert r["nominal"]["configurations"][end] == r["optimised"]["configurations"][end]
    assert r["claims"]["nominal"] == tr[0] and r["claims"]["final"] == tr[-1]
    assert (root / r["figures"]["fig7"]).stat().st_size > 0
    assert (root / r["figures"]["fig7_html"]).stat().st_size > 0
    assert calls[-1] == ("mdn: Fig. 7 (BO)", SMALL.bo_iterations, SMALL.bo_iterations)
    assert "seconds" not in r  # wall-clock times stay out of the results


def test_stored_bounds_match_an_independent_evaluation(fig7, tol):
    """The optimised trajectory's eq. 9 values recomputed from its configurations with a fresh
    model and chest (one batch, not the optimiser's one-at-a-time calls)."""
    from riskplan.kinematics import load_model
    from riskplan.planning.chest_scene import build_chest
    from riskplan.planning.risk import ConfigurationBound

    _, r, _ = fig7
    bound = ConfigurationBound(
        load_model(r["model"]), build_chest(r["chest_seed"]).base_environment
    )
    for name in ("nominal", "optimised"):
        got = bound(np.asarray(r[name]["configurations"]))
        np.testing.assert_allclose(got, r[name]["bounds_eq9"], **tol["float32_ref"])


def test_robot_executions_of_both_trajectories(fig7):
    """Fig. 7 on the robot: both trajectories executed the same number of times, on the default
    recess goal (free on the robot: its configuration collides in no more than 5 % of them)."""
    from riskplan.planning.chest import DEFAULT_GOAL

    _, r, _ = fig7
    rows = {row["name"]: row for row in r["robot"]}
    assert set(rows) == {"nominal", "optimised"}
    np.testing.assert_array_equal(r["goal"], DEFAULT_GOAL)
    for row in rows.values():
        assert row["n_robot"] == SMALL.robot_executions
        assert row["robot_disks_low"] <= row["robot_disks_mc"] <= row["robot_disks_high"]
        assert row["robot_disks_per_config"][-1] <= 0.05
        assert row["robot_disks_per_config"][0] <= 0.05
        # the body of backbone and disks lies inside the 10 mm tube: never more collisions
        assert row["robot_disks_hits"] <= row["robot_hits"]


def test_rerun_reads_the_store_and_gives_identical_results(fig7, tmp_path, monkeypatch):
    import riskplan.planning.chest as chest

    root, ref, _ = fig7
    copy = tmp_path / "copy"
    shutil.copytree(root / "store", copy)

    def no_planning(*a, **k):
        raise AssertionError("a rerun must read the stored record, not plan again")

    monkeypatch.setattr(chest, "plan_chest", no_planning)
    again = run_fig7(tmp_path / "mdn", SMALL, ResultStore(copy, CONFIG), seed=0)
    assert json.dumps(again, sort_keys=True) == json.dumps(ref, sort_keys=True)
    assert (tmp_path / "mdn" / "fig7.png").exists()  # figures redrawn from the record


def test_corrupted_record_is_refused(fig7, tmp_path):
    root, _, _ = fig7
    copy = tmp_path / "copy"
    shutil.copytree(root / "store", copy)
    rec = copy / "records" / "mdn.fig7.json"
    obj = json.loads(rec.read_text())
    obj["payload"]["trace"][-1] = 0.01  # a better-looking number than was computed
    rec.write_text(json.dumps(obj))
    with pytest.raises(DataFormatError, match=r"mdn\.fig7\.json"):
        run_fig7(tmp_path / "mdn", SMALL, ResultStore(copy, CONFIG), seed=0)


def test_claim_is_computed_from_the_numbers():
    n = MDN["bo_iterations"]["value"]
    after = MDN["collision_after"]["value"]
    # fewer iterations, already below: decided (the bound never rises)
    c = fig7_claims([0.16, 0.1, after / 2])
    assert c["below_after_paper_iterations"] is True and c["at_paper_iterations"] is None
    assert c["reduction"] == pytest.approx(1 - (after / 2) / 0.16)
    # fewer iterations, not yet below: undecided
    assert fig7_claims([0.16, 0.12])["below_after_paper_iterations"] is None
    # the paper's number of iterations: read off the trace at that iteration
    tr = list(np.linspace(0.16, after + 0.01, n + 1)) + [after / 2] * 5
    c = fig7_claims(tr)
    assert c["below_after_paper_iterations"] is False
    assert c["at_paper_iterations"] == pytest.approx(after + 0.01)
    assert c["final"] == after / 2
    # other paper values give other verdicts (nothing is hard-coded)
    paper = {**MDN, "collision_after": {"value": 0.2}}
    assert fig7_claims(tr, paper)["below_after_paper_iterations"] is True
    assert fig7_claims([0.3, 0.25], paper)["below_after_paper_iterations"] is None
    with pytest.raises(InvalidInputError, match="trace"):
        fig7_claims([0.2, 1.5])
    with pytest.raises(InvalidInputError, match="trace"):
        fig7_claims([])


def test_bad_scale():
    with pytest.raises(InvalidInputError, match="bo_iterations"):
        MDNScale(bo_iterations=-1)
    with pytest.raises(InvalidInputError, match="milestones"):
        MDNScale(milestones=0)


def test_report_shows_the_panel(fig7, tmp_path):
    from riskplan.app.reproduce.report import write_report

    root, r, _ = fig7
    out = tmp_path / "rep"
    shutil.copytree(root / "mdn", out / "mdn")
    results = {"config": {"paper": "mdn", "scale": "test", "seed": 0}, "mdn": {"fig7": r}}
    path = write_report(out, results, ResultStore(root / "store", CONFIG), {"backend": "serial"})
    text = path.read_text()
    assert "Fig. 7" in text and "fig7.html" in text
    assert f"{100 * r['claims']['nominal']:.2f}" in text
    assert f"{100 * r['claims']['final']:.2f}" in text


def test_cli_prints_the_claim(fig7, tmp_path, monkeypatch):
    from typer.testing import CliRunner

    import riskplan.app.reproduce.pipeline as rp
    from riskplan.cli import app

    _, r, _ = fig7
    monkeypatch.setattr(rp, "reproduce", lambda out, **k: {"config": {}, "mdn": {"fig7": r}})
    res = CliRunner().invoke(app, ["reproduce", "--paper", "mdn", "--out", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    c = r["claims"]
    assert (
        f"{100 * c['nominal']:.1f} % -> {100 * c['final']:.1f} % after 3 iterations" in res.output
    )
