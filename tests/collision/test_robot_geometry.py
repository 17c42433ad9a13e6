"""Backbone curves and the mixtures built from them."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.kinematics.robot_mixture import arc_backbone, backbone_mixture
from tests.conftest import TOL


def test_arc_closed_form():
    k, L = 5.0, 0.2
    P = arc_backbone(k, np.pi / 2, L)
    np.testing.assert_allclose(
        P[-1], [0.0, (1 - np.cos(k * L)) / k, np.sin(k * L) / k], **TOL["float64_ref"]
    )
    steps = np.linalg.norm(np.diff(P, axis=0), axis=1)
    np.testing.assert_allclose(steps.sum(), L, **TOL["chord_length"])  # a unit-speed curve
    straight = arc_backbone(0.0, 0.0, L)
    np.testing.assert_allclose(straight[:, 2], np.linspace(0, L, 41), **TOL["float64_ref"])
    assert arc_backbone(np.zeros((2, 3)), 0.0).shape == (2, 3, 41, 3)


def test_backbone_mixture():
    P = arc_backbone(np.array([0.0, 4.0]), 0.0)
    gm = backbone_mixture(P, 5, radius=0.01, sigma=0.002)
    assert tuple(gm.batch_shape) == (2,) and gm.n_components == 5 and gm.dim == 3
    m = gm.numpy()["means"]
    np.testing.assert_allclose(m[0, :, :2], 0.0, **TOL["float64_abs"])
    assert np.all(np.diff(m[0, :, 2]) > 0)
    cov = gm.covariances.numpy()
    # straight robot: variance across the backbone = radius^2 / 4 + sigma^2
    np.testing.assert_allclose(cov[0, :, 0, 0], 0.01**2 / 4 + 0.002**2, **TOL["float64_ref"])
    with pytest.raises(InvalidInputError):
        backbone_mixture(np.zeros((5, 3)), 5)


class _ArcRobot:
    """Duck-typed robot: tendon j bends towards angle 2*pi*j/m with curvature 200 * d_j (1/m per m)."""

    n_tendons = 4
    displacement_limits = np.array([[-0.01, 0.04]] * 4)

    def solve_displacements(self, d):
        from types import SimpleNamespace

        d = np.asarray(d, dtype=np.float64)
        ang = 2 * np.pi * np.arange(4) / 4
        v = (d * 200.0) @ np.column_stack([np.cos(ang), np.sin(ang)])
        return SimpleNamespace(
            positions=arc_backbone(np.linalg.norm(v, axis=-1), np.arctan2(v[..., 1], v[..., 0]))
        )


def test_robot_mixture_uses_robot_backbone():
    from riskplan.kinematics.robot_mixture import robot_mixture

    gm = robot_mixture(_ArcRobot(), np.array([[0.0, 0, 0, 0], [0.02, 0, 0, 0]]))
    ref = backbone_mixture(arc_backbone(np.array([0.0, 4.0]), 0.0), 5)
    np.testing.assert_allclose(gm.means.numpy(), ref.means.numpy(), **TOL["float64_ref"])
