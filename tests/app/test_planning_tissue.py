"""The tissue-planning experiment module: output files (npz, JSON, PNG, GIF) are complete
and consistent with the run, written atomically."""

from __future__ import annotations

import json

import numpy as np
from PIL import Image

from riskplan.app.outputs.tissue_plan import _pack, summary_rows, write_outputs
from riskplan.scenarios.uncertainty import get_case
from riskplan.tissue_planning.calibration import CalibrationRow
from riskplan.tissue_planning.plan import TissuePlanningResult
from riskplan.tissue_planning.select import select_plan
from tests.conftest import TOL
from tests.planning.conftest import SMALL_MESH, near_needle, needle_result  # noqa: F401 (fixtures)


def test_pack_layout(needle_result):  # noqa: F811
    plans, _ = needle_result
    packed = _pack(plans)
    for i, p in enumerate(plans):
        c = packed["controls"][packed["control_offsets"][i] : packed["control_offsets"][i + 1]]
        x = packed["reduced"][packed["state_offsets"][i] : packed["state_offsets"][i + 1]]
        assert np.array_equal(c, p.controls) and np.array_equal(x, p.reduced)


def test_write_outputs(tmp_path, near_needle, needle_result):  # noqa: F811
    plans, trees = needle_result
    case = get_case("actuation", SMALL_MESH)
    sel = select_plan(
        near_needle, plans[:2], case, n_samples=2, n_goal_samples=200, seed=0, backend="serial"
    )
    row = CalibrationRow(index=sel.best, rank=1, p_lqgmp=0.9, p_mc=0.8, low=0.7, high=0.95, n=100)
    res = TissuePlanningResult(
        "needle", "actuation", 0, near_needle, plans[:2], trees, sel, [row], {"rrt": 1.0}
    )
    files = write_outputs(res, tmp_path, gif=True)
    assert set(files) == {
        "candidates.npz",
        "candidates.json",
        "selected.npz",
        "selected.json",
        "selected_controls.csv",
        "selected_gains.npz",
        "candidates.png",
        "execution.gif",
    }
    with np.load(files["selected.npz"]) as z:
        assert np.array_equal(z["controls"], sel.plan.controls)
        assert np.array_equal(z["L"], sel.controller.L) and z["K"].shape == sel.controller.K.shape
    meta = json.loads(files["selected.json"].read_text())
    assert meta["index"] == sel.best and meta["p_success"] == sel.score(sel.best).p_success
    assert meta["calibration_check"][0]["inside"] is True
    # ranks are counted the same way in the table and the file: 1 = the selected plan
    assert meta["calibration_check"][0]["rank"] == summary_rows(res)[0][1] == 1
    from riskplan.planning.export import read_tissue_plan

    exp = read_tissue_plan(files["selected_controls.csv"], files["selected_gains.npz"])
    assert np.array_equal(exp["controls"], sel.plan.controls)
    assert np.array_equal(exp["gains"]["L"], sel.controller.L)
    # per-step risk: the per-step factors of LQG-MP's P(no collision) multiply to it
    np.testing.assert_allclose(
        np.prod(1.0 - exp["risk"]), sel.result.p_collision_free, **TOL["float64_exact"]
    )
    np.testing.assert_allclose(
        exp["time_s"], near_needle.config.tau * np.arange(sel.plan.n_steps), **TOL["float64_exact"]
    )
    cand = json.loads(files["candidates.json"].read_text())
    assert [s["index"] for s in cand["scores"]] == [0, 1] and len(cand["trees"]) == len(trees)
    with Image.open(files["execution.gif"]) as im:
        assert im.n_frames >= 2
    assert summary_rows(res)[0][:2] == [sel.best, 1]
    assert not list(tmp_path.glob(".*"))  # no temporary files left
