"""The risk-calibration study (app/reproduce/risk_calibration.py) at its smoke size: metrics
against closed forms, the study's records, and a rerun that reads them instead of executing."""

from __future__ import annotations

import json

import numpy as np
import pytest

from riskplan.app.reproduce.risk_calibration import (
    RISK_STUDY_SCALES,
    RiskStudyScale,
    calibration_metrics,
    cross_fitted_logistic,
    run_risk_study,
)
from riskplan.app.store import ResultStore
from tests.conftest import TOL

SMOKE = RISK_STUDY_SCALES["smoke"]
CONFIG = {"test": "risk", "seed": 0}


def test_metrics_closed_form():
    p = np.array([0.1, 0.5, 0.9, 0.0])
    r = np.array([0.2, 0.5, 1.0, 0.0])
    m = calibration_metrics(p, r)
    assert m["n_mid"] == 2 and m["n"] == 4
    np.testing.assert_allclose(m["mae_mid"], 0.05, **TOL["float64_exact"])
    np.testing.assert_allclose(m["mae_all"], 0.2 / 4, **TOL["float64_exact"])
    brier = np.mean(r * (1 - p) ** 2 + (1 - r) * p**2)
    np.testing.assert_allclose(m["brier"], brier, **TOL["float64_exact"])
    # a perfect predictor of deterministic outcomes scores 0; a coin toss 0.25
    assert calibration_metrics([0.0, 1.0], [0.0, 1.0])["brier"] == 0.0
    assert calibration_metrics([0.5, 0.5], [0.0, 1.0])["brier"] == 0.25


def test_cross_fitted_logistic_recovers_the_map_and_never_sees_the_item():
    """Rates drawn from a known logistic map of the clearances: the held-out predictions
    follow the true probabilities (within the binomial noise of 200 executions and the fit's
    own error), and an item's prediction does not move when its own count changes."""
    from scipy.special import expit

    rng = np.random.default_rng(4)
    n_items, s, execs = 300, 64, 200
    centre = rng.uniform(-1.5, 1.5, n_items)  # mm
    gaps = (centre[:, None] + 0.4 * rng.standard_normal((n_items, s))) * 1e-3  # m
    a, b = 0.5, 3.0
    truth = expit(a - b * gaps * 1e3).mean(axis=1)
    rates = rng.binomial(execs, truth) / execs
    groups = np.arange(n_items) < 250
    held, fits = cross_fitted_logistic(gaps, rates, execs, groups, seed=0)
    # binomial sd at p = 1/2 and n = 200 is 0.035 per item; the fitted map is far closer
    assert np.abs(held - truth).mean() < 0.02
    assert len(fits) == 2 and all(abs(f["b"] - b) < 0.5 for f in fits)
    flipped = rates.copy()
    flipped[0] = 1.0 - flipped[0]
    again, _ = cross_fitted_logistic(gaps, flipped, execs, groups, seed=0)
    assert again[0] == held[0] and not np.array_equal(again, held)


def test_scale_errors():
    from riskplan.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="configurations"):
        RiskStudyScale(configurations=0)
    with pytest.raises(InvalidInputError, match="coherences"):
        RiskStudyScale(coherences=(1.5,))
    with pytest.raises(InvalidInputError, match="extents"):
        RiskStudyScale(extents=(0.0,))
    with pytest.raises(InvalidInputError, match="draws"):
        RiskStudyScale(draws=0)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    root = tmp_path_factory.mktemp("risk")
    return root, run_risk_study(root / "out", SMOKE, ResultStore(root / "store", CONFIG), seed=0)


def test_study_records(study):
    root, r = study
    n_c, n_t = SMOKE.configurations, SMOKE.trajectories
    assert len(r["measured"]["configurations"]) == n_c
    assert len(r["measured"]["trajectories"]) == n_t
    for pr in r["predicted"].values():
        p = np.r_[pr["configurations"], pr["trajectories"]]
        assert p.shape == (n_c + n_t,) and np.all((p >= 0) & (p <= 1))
    assert set(r["predicted"]) == {"eq9 / eq10", "cloud ρ=0.5", "bodies c=2", "logistic c=2"}
    # stratified: two thirds of the configurations were near contact (|clearance| < band)
    c = np.abs(r["nominal_clearance"])
    assert (c < SMOKE.band).sum() >= 2 * n_c // 3
    assert (root / "out" / "risk_calibration.png").stat().st_size > 0
    assert json.loads((root / "out" / "risk_calibration.json").read_text())["seed"] == 0


def test_cloud_risk_beats_eq9_on_the_same_executions(study):
    """The effect and its counterfactual on common draws: against the same robot executions the
    body-contact risk scores a lower Brier score than the paper's eq. 9/10 (docs/validation.md
    has the size at the reduced scale: 0.136 against 0.406)."""
    _, r = study
    m = r["metrics"]
    assert m["cloud ρ=0.5"]["all"]["brier"] < m["eq9 / eq10"]["all"]["brier"]
    # recomputed from the stored numbers, not read from the summary
    meas = np.r_[r["measured"]["configurations"], r["measured"]["trajectories"]]
    assert m["bodies c=2"]["all"]["brier"] < m["eq9 / eq10"]["all"]["brier"]
    for name in ("cloud ρ=0.5", "eq9 / eq10", "bodies c=2"):
        p = np.r_[r["predicted"][name]["configurations"], r["predicted"][name]["trajectories"]]
        brier = np.mean(meas * (1 - p) ** 2 + (1 - meas) * p**2)
        np.testing.assert_allclose(m[name]["all"]["brier"], brier, **TOL["float64_exact"])


def test_rerun_reads_the_store(study, tmp_path, monkeypatch):
    import shutil

    import riskplan.planning.validate as validate

    root, ref = study
    shutil.copytree(root / "store", tmp_path / "store")

    def no_execution(*a, **k):
        raise AssertionError("a rerun must read the stored executions")

    monkeypatch.setattr(validate, "execute_on_robot", no_execution)
    again = run_risk_study(tmp_path / "out", SMOKE, ResultStore(tmp_path / "store", CONFIG), seed=0)
    assert again["measured"] == ref["measured"] and again["predicted"] == ref["predicted"]


def test_transmission_mechanism_all_sources_is_the_robot():
    """The mechanism's "all sources" rate is the robot's own executions (same seeds, same body
    test); start history and offsets alone are rates of the same configurations."""
    from riskplan.app.reproduce.risk_calibration import transmission_mechanism
    from riskplan.planning.chest_scene import build_chest
    from riskplan.planning.validate import execute_on_robot

    x = np.array([[0.008256, -0.004725, 0.021455, 0.036358]])  # near contact on the robot
    m = transmission_mechanism(x, [0.33], executions=40, seed=11)
    robot = execute_on_robot(
        "paper", x, build_chest(0).base_environment, 40, seed=11, body="disks", backend="serial"
    )
    assert m["rates"]["all sources"][0] == robot.per_configuration.probability[0]
    assert 0.0 < m["rates"]["all sources"][0] < 1.0
    assert set(m["mae_mid"]) == {"all sources", "start history", "offsets"}
    assert 0.0 <= m["pattern_share_median"] <= 1.0


def test_reproduce_robot_risk_stage_resumes(tmp_path, monkeypatch):
    """``reproduce --paper mdn --stage robot-risk`` at smoke size: the study's summary in
    results.json (``mdn.robot_risk.<risk>``) and the report; a rerun reads every finished
    record (no robot execution, no risk recomputed) and a removed record alone is redone."""
    import riskplan.planning.validate as validate
    from riskplan.app.reproduce import pipeline as rep
    from riskplan.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="robot_risk_scale"):
        rep.reproduce(tmp_path / "bad", paper="mdn", stages=("robot-risk",), robot_risk_scale="x")
    out = tmp_path / "out"
    first = rep.reproduce(out, paper="mdn", stages=("robot-risk",), backend="serial")
    saved = json.loads((out / "results.json").read_text())
    assert set(saved["mdn"]) == {"robot_risk"}  # the figures did not run
    rr = saved["mdn"]["robot_risk"]
    keys = ["eq9", "cloud_rho=0.5", "bodies_c=2", "logistic_c=2"]
    assert rr["scale"] == "smoke" and rr["risks"] == keys
    study = json.loads((out / "robot-risk" / "risk_calibration.json").read_text())
    labels = ("eq9 / eq10", "cloud ρ=0.5", "bodies c=2", "logistic c=2")
    for key, label in zip(rr["risks"], labels):
        m = rr[key]
        assert set(m) >= {"mae_band", "brier", "n_band", "n", "spearman"}
        assert m["n"] == SMOKE.configurations + SMOKE.trajectories
        assert m["brier"] == study["metrics"][label]["all"]["brier"]
        assert 0 <= m["n_band"] <= m["n"]
    html = (out / "report.html").read_text()
    assert "a risk the robot agrees with" in html and (out / rr["figure"]).stat().st_size > 0

    def refuse(*a, **k):
        raise AssertionError("finished work must be read from the store")

    monkeypatch.setattr(validate, "execute_on_robot", refuse)
    monkeypatch.setattr("riskplan.planning.risk.SampledBodyRisk", refuse)
    (out / "robot-risk" / "store" / "records" / "risk.cloud.0.5.json").unlink()
    calls = []
    import riskplan.collision.body_risk as body_risk

    real = body_risk.cloud_risk

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(body_risk, "cloud_risk", counted)
    again = rep.reproduce(out, paper="mdn", stages=("robot-risk",), backend="serial")
    assert len(calls) == SMOKE.configurations + SMOKE.trajectories  # the removed record only
    assert again["mdn"]["robot_risk"] == first["mdn"]["robot_risk"]
