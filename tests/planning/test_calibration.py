"""Calibration metrics of predicted P(success) against measured rates (planning.select)."""

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.tissue_planning.calibration import SATURATED, calibration_metrics, evenly_spaced_ranks
from tests.conftest import TOL


def _ranks(v):
    # average ranks of ties, written out independently of scipy
    order = np.argsort(v, kind="stable")
    r = np.empty(len(v))
    r[order] = np.arange(len(v), dtype=float)
    for x in np.unique(v):
        idx = v == x
        r[idx] = r[idx].mean()
    return r


def test_metrics_against_closed_forms():
    rng = np.random.default_rng(3)
    measured = rng.uniform(0.1, 0.9, 25)
    predicted = np.clip(measured + rng.normal(0, 0.1, 25), 0, 1)
    predicted[3] = predicted[4]  # a tie
    c = calibration_metrics(predicted, measured)
    np.testing.assert_allclose(c.mae, np.mean(np.abs(predicted - measured)), **TOL["float64_exact"])
    rho = np.corrcoef(_ranks(predicted), _ranks(measured))[0, 1]
    np.testing.assert_allclose(c.spearman, rho, **TOL["float64_exact"])
    assert c.n_plans == 25
    np.testing.assert_allclose(c.measured_spread, np.ptp(measured), **TOL["float64_exact"])
    assert c.informative


def test_perfect_reversed_and_goal():
    r = np.linspace(0.2, 0.9, 8)
    good = calibration_metrics(r, r)
    assert good.mae == 0.0 and good.spearman == pytest.approx(1.0) and good.meets_goal
    bad = calibration_metrics(r[::-1], r)
    assert bad.spearman == pytest.approx(-1.0) and not bad.meets_goal
    # a constant offset keeps the ranks but misses the error goal
    off = calibration_metrics(np.clip(r + 0.1, 0, 1), r)
    assert off.spearman == pytest.approx(1.0) and off.mae > 0.05 and not off.meets_goal


def test_saturated_or_constant_sets_are_not_informative():
    r = np.array([SATURATED, 0.99, 1.0, 1.0])
    p = np.array([0.5, 0.7, 0.9, 0.95])
    c = calibration_metrics(p, r)
    assert c.spearman is not None and not c.informative and not c.meets_goal
    flat = calibration_metrics(p, np.full(4, 0.5))
    assert flat.spearman is None and not flat.informative
    assert calibration_metrics([0.1, 0.2], [0.3, 0.1]).spearman is None  # too few pairs


@pytest.mark.parametrize(
    "p, r", [([], []), ([0.1, 0.2], [0.1]), ([1.2, 0.1, 0.2], [0.1, 0.2, 0.3]), ([np.nan], [0.1])]
)
def test_bad_input(p, r):
    with pytest.raises(InvalidInputError):
        calibration_metrics(p, r)


def test_evenly_spaced_ranks():
    assert evenly_spaced_ranks(100, 20)[0] == 0 and evenly_spaced_ranks(100, 20)[-1] == 99
    assert len(evenly_spaced_ranks(100, 20)) == 20
    assert evenly_spaced_ranks(5, 20) == [0, 1, 2, 3, 4]
    with pytest.raises(InvalidInputError):
        evenly_spaced_ranks(0, 3)
