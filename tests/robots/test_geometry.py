"""Surface sampling of the robot body: points on the surfaces, unit outward normals."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.robots.geometry import (
    BodyGeometry,
    interpolate_frames,
    sample_disk,
    sample_surface,
    sample_tube,
)
from tests.conftest import TOL


def arc_frames(kappa: float, length: float = 0.2, n: int = 41):
    """Exact frames of a planar constant-curvature arc bending towards +x (x-z plane)."""
    s = np.linspace(0.0, length, n)
    a = kappa * s
    P = np.stack([(1 - np.cos(a)) / kappa, 0 * s, np.sin(a) / kappa], -1)
    R = np.zeros((n, 3, 3))
    R[:, 0, 0], R[:, 0, 2] = np.cos(a), np.sin(a)
    R[:, 1, 1] = 1.0
    R[:, 2, 0], R[:, 2, 2] = -np.sin(a), np.cos(a)
    return s, P, R


def dist_to_arc(x, kappa, length):
    """Distance of points to the arc (the circle of radius 1/kappa about (1/kappa, 0, 0) in the x-z plane)."""
    c = np.array([1 / kappa, 0.0, 0.0])
    d = x - c
    # angle of the projection onto the x-z plane, measured like the arc parameter
    ang = np.arctan2(d[:, 2], -d[:, 0])
    ang = np.clip(ang, 0.0, kappa * length)
    foot = c + np.stack([-np.cos(ang), 0 * ang, np.sin(ang)], -1) / kappa
    return np.linalg.norm(x - foot, axis=1)


BODY = BodyGeometry(0.003, 0.01, 0.002, tuple(0.2 * np.arange(1, 10) / 9), spacing=0.001)


@pytest.mark.parametrize("kappa", [1e-3, 5.0, 12.0])
def test_tube_points_at_radius_from_backbone(kappa):
    s, P, R = arc_frames(kappa)
    # interior stations only (no end effects of the clamp to [0, L])
    pts, nrm = sample_tube(s, P, R, 0.003, 0.0007, exclude=[(-1, 0.002), (0.198, 1)])
    d = dist_to_arc(pts, kappa, 0.2)
    # between nodes: Hermite positions (4th order) and projected linear rotations (2nd order,
    # r (kappa h)^2 / 8 = 1.4 um at kappa = 12, h = 5 mm)
    np.testing.assert_allclose(d, 0.003, **TOL["surface_sampling"])
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, **TOL["float64_ref"])
    # outward: moving along the normal increases the distance to the backbone
    d_out = dist_to_arc(pts + 1e-4 * nrm, kappa, 0.2)
    assert np.all(d_out > d)


def test_tube_exact_at_nodes():
    s, P, R = arc_frames(8.0, n=21)
    pts, _ = sample_tube(s, P, R, 0.003, 0.01)  # spacing = node spacing: samples sit on nodes
    d = dist_to_arc(pts, 8.0, 0.2)
    np.testing.assert_allclose(d, 0.003, **TOL["float64_ref"])


def test_interpolated_frames_orthonormal_and_exact_at_nodes():
    s, P, R = arc_frames(10.0)
    Pi, Ri = interpolate_frames(s, P, R, s)
    np.testing.assert_allclose(Pi, P, **TOL["float64_exact"])
    np.testing.assert_allclose(Ri, R, **TOL["float64_ref"])
    _, Rm = interpolate_frames(s, P, R, 0.5 * (s[1:] + s[:-1]))
    np.testing.assert_allclose(
        np.einsum("kji,kjl->kil", Rm, Rm),
        np.broadcast_to(np.eye(3), Rm.shape),
        **TOL["float64_ref"],
    )


def test_disk_points_on_cylinder_with_outward_normals(rng):
    c = rng.normal(size=3)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    pts, nrm = sample_disk(c, Q, 0.01, 0.002, 0.003, 0.0005)
    local = (pts - c) @ Q  # body coordinates
    rho, h = np.hypot(local[:, 0], local[:, 1]), local[:, 2]
    side = np.isclose(rho, 0.01, **TOL["float64_abs"])
    face = np.isclose(np.abs(h), 0.001, **TOL["float64_abs"])
    assert np.all(side | face)
    assert (
        np.all(np.abs(h) <= 0.001 + TOL["float64_abs"]["atol"])
        and np.all(rho <= 0.01 + TOL["float64_abs"]["atol"])
        and np.all(rho[face] >= 0.003)
    )
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, **TOL["float64_ref"])
    nl = nrm @ Q
    # outward: radial on the side, +-axis on the faces
    np.testing.assert_allclose(
        nl[side & ~face][:, :2], local[side & ~face][:, :2] / 0.01, **TOL["float64_ref"]
    )
    np.testing.assert_allclose(
        nl[face & ~side][:, 2], np.sign(h[face & ~side]), **TOL["float64_ref"]
    )


def test_whole_surface_is_on_the_union_boundary():
    s, P, R = arc_frames(6.0)
    pts, nrm = sample_surface(s, P, R, BODY)
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, **TOL["float64_ref"])
    # no sample lies inside the tube or inside a disk (the inner rim of a disk face, planar at
    # rho = r, dips into the curved tube by at most kappa r t / 2 = 18 um here)
    d = dist_to_arc(pts, 6.0, 0.2)
    assert np.all(d >= 0.003 - 2e-5)
    Pd, Rd = interpolate_frames(s, P, R, np.array(BODY.disk_s))
    for c, Q in zip(Pd, Rd):
        loc = (pts - c) @ Q
        depth = np.minimum(0.01 - np.hypot(loc[:, 0], loc[:, 1]), 0.001 - np.abs(loc[:, 2]))
        # tube stations are cut at |s - s_k| = t/2: on the inside of the bend the tube surface
        # reaches into the disk by at most kappa r t / 2 = 18 um (hidden behind the disk faces)
        assert (
            depth.max() <= 1.05 * 6.0 * 0.003 * 0.002 / 2
        )  # first-order bound, 5 % for higher orders


def test_batch_equals_loop():
    frames = [arc_frames(k) for k in (2.0, 7.0, 11.0)]
    s = frames[0][0]
    P = np.stack([f[1] for f in frames])
    R = np.stack([f[2] for f in frames])
    bp, bn = sample_surface(s, P, R, BODY)
    for j, (_, Pj, Rj) in enumerate(frames):
        lp, ln = sample_surface(s, Pj, Rj, BODY)
        np.testing.assert_allclose(bp[j], lp, **TOL["float64_exact"])
        np.testing.assert_allclose(bn[j], ln, **TOL["float64_exact"])


def test_bad_input():
    s, P, R = arc_frames(5.0)
    with pytest.raises(InvalidInputError, match="positions"):
        sample_surface(s, P[:-1], R, BODY)
    bad = P.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InvalidInputError, match="NaN"):
        sample_surface(s, bad, R, BODY)
    with pytest.raises(InvalidInputError, match="disk_radius"):
        BodyGeometry(0.003, 0.002, 0.002, (0.1,))
