from __future__ import annotations

import numpy as np
import pytest

from riskplan.deformable import (
    body_load,
    locate,
    patch_load,
    patch_weights,
    point_load,
    traction_load,
)
from riskplan.errors import InvalidInputError
from tests.conftest import TOL


def test_point_load_resultant_and_moment(poly200, rng, tol):
    pts = np.array([[0.3, 0.2], [0.9, 0.25]])
    F = rng.normal(size=(2, 2))
    f = point_load(poly200, pts, F)
    np.testing.assert_allclose(f.sum(0), F.sum(0), **tol["float64_exact"])
    # moment about the origin is preserved (P1 weights reproduce linear functions)
    cross = lambda x, y: x[:, 0] * y[:, 1] - x[:, 1] * y[:, 0]  # noqa: E731
    np.testing.assert_allclose(
        cross(poly200.nodes, f).sum(), cross(pts, F).sum(), **tol["float64_exact"]
    )
    np.testing.assert_allclose(f, locate(poly200, pts).spread(F), **tol["float64_exact"])


@pytest.mark.parametrize("on", ["boundary", "area"])
def test_patch_weights_sum_to_one_and_stay_local(square175, on, tol):
    c, R = np.array([1.0, 0.5]), 0.15
    w = patch_weights(square175, c, R, on=on)
    np.testing.assert_allclose(w.sum(), 1.0, **tol["float64_exact"])
    assert np.all(w >= 0)
    far = np.linalg.norm(square175.nodes - c, axis=1) > R + square175.h
    assert np.all(w[far] == 0)
    if on == "boundary":
        assert np.all(w[np.setdiff1d(np.arange(square175.n_nodes), square175.boundary_nodes)] == 0)
    f = patch_load(square175, c, R, [2.0, -1.0], on=on)
    np.testing.assert_allclose(f.sum(0), [2.0, -1.0], **tol["float64_exact"])
    # the bump is symmetric about y = 0.5 on the right edge: load centroid is at the centre's y
    np.testing.assert_allclose((w * square175.nodes[:, 1]).sum(), 0.5, **TOL["patch_centroid"])


def test_patch_load_errors(square175):
    with pytest.raises(InvalidInputError, match="no boundary"):
        patch_weights(square175, [0.5, 0.5], 0.1)
    with pytest.raises(InvalidInputError, match="radius"):
        patch_weights(square175, [1.0, 0.5], -0.1)
    with pytest.raises(InvalidInputError, match="on"):
        patch_weights(square175, [1.0, 0.5], 0.1, on="volume")


def test_body_load_integrates_linear_field(poly200, tol):
    # Σ_a f_a = ∫ b dx and Σ_a f_a x_a = ∫ b x dx (exact for polynomial b of degree <= 3)
    b = lambda x: np.stack([1.0 + x[:, 0] ** 2, x[:, 1] * x[:, 0]], axis=1)  # noqa: E731
    f = body_load(poly200, b)
    fine = body_load(poly200, b, refine=3)
    np.testing.assert_allclose(f, fine, **tol["float64_ref"])
    const = body_load(poly200, [0.0, -2.0])
    np.testing.assert_allclose(const.sum(0), [0.0, -2.0 * poly200.area], **tol["float64_exact"])


def test_traction_of_constant_stress_is_self_equilibrated(poly200, tol):
    sig = np.array([[1.0, 0.3], [0.3, -0.5]])
    f = traction_load(poly200, lambda x, n: n @ sig.T)
    np.testing.assert_allclose(f.sum(0), 0.0, **TOL["float64_abs"])
    # uniform traction on the bottom edge (y = 0) only
    be = poly200.boundary_edges
    bottom = be[np.all(poly200.nodes[be][:, :, 1] == 0.0, axis=1)]
    fb = traction_load(poly200, [0.0, -1.0], edges=bottom)
    np.testing.assert_allclose(fb.sum(0), [0.0, -1.2], **tol["float64_exact"])
