"""The optimiser comparison at small scale: same budget per method, summaries consistent with rows."""

from __future__ import annotations

import numpy as np

from riskplan.app.reproduce.optimiser_comparison import (
    compare_optimisers,
    summarise,
    to_markdown,
    trace_table,
)
from riskplan.planning.prm import MeanValidity, build_roadmap, interpolate_path
from riskplan.planning.risk import ConfigurationBound, trajectory_risk
from tests.planning.conftest import GOAL, START, AnalyticModel, box_env


def test_compare_small():
    model = AnalyticModel()
    env = box_env([0.0, 0.0, 0.1], [0.03, 0.03, 0.03])
    validity = MeanValidity(model, env)
    rm = build_roadmap(validity, n_milestones=20, seed=0)
    nominal = interpolate_path(rm.shortest_path(START, GOAL), 0.005)
    bound = ConfigurationBound(model, env)
    _, p = trajectory_risk(bound, nominal)
    problem = {
        "model": model,
        "validity": validity,
        "bound": bound,
        "nominal": nominal,
        "bounds": p,
    }
    rows = compare_optimisers(
        problem, methods=("random", "bo"), seeds=(0, 1), iterations=1, backend="serial"
    )
    assert [(r["method"], r["seed"]) for r in rows] == [
        ("random", 0),
        ("random", 1),
        ("bo", 0),
        ("bo", 1),
    ]
    assert all(r["bound"] <= r["initial_bound"] and r["evaluations"] <= 1 for r in rows)
    s = summarise(rows)
    assert s[0]["median_bound"] == np.median([r["bound"] for r in rows[:2]])
    assert "| bo |" in to_markdown(s, rows[0]["initial_bound"]) and "after" in trace_table(
        rows, at=(1,)
    )
