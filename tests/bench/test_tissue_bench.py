"""The tissue benchmark runs, reports exactly the issue's keys, and its steps do real work
(no timing assertions)."""

from __future__ import annotations

import numpy as np

from riskplan.bench import tissue
from tests.conftest import TOL


def test_bench_keys():
    figures = tissue.run(quick=True)
    assert set(figures) == {
        "linear_step_ms_175",
        "linear_step_ms_1000",
        "nonlinear_step_ms_175",
        "nonlinear_step_ms_1000",
    }
    assert all(np.isfinite(v) and v > 0 for v in figures.values())


def test_bench_setups_are_the_stated_problems():
    mesh, model, pts = tissue._linear_setup(175)
    assert mesh.n_elements == 175 and pts.n_points == 12
    mesh, model, W, pts = tissue._nonlinear_setup(175)
    assert mesh.n_elements == 175 and W.shape == (mesh.n_nodes, 3)
    np.testing.assert_allclose(W.sum(0), 1.0, **TOL["float64_exact"])
    f = W @ np.array([[1.0, 0.2], [0.1, -1.0], [-0.8, -0.3]])
    u = model.solve(f)
    assert np.linalg.norm(model.residual(u, f)) <= model.rtol * np.linalg.norm(f) + model.atol
    assert np.abs(u).max() > 1e-3  # the load deforms the body visibly
