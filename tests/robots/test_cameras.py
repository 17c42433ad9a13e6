"""Simulated depth cameras: exact depths without noise, facing/occlusion, two views, noise std."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.robots.cameras import (
    PinholeCamera,
    capture,
    default_cameras,
    depth_image,
    project,
    render,
    visible_samples,
)
from tests.conftest import TOL


def fib_sphere(center, radius, n):
    """Nearly uniform points on a sphere (Fibonacci lattice) with outward normals."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5**0.5) * k
    r = np.sqrt(1 - z * z)
    nrm = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
    return center + radius * nrm, nrm


def cam_at(pos, target, **kw):
    return PinholeCamera.look_at(
        pos, target, (0.0, 0.0, 1.0), width=160, height=120, hfov_deg=60.0, **kw
    )


def test_plane_depths_exact_without_noise(rng):
    # plane x = 0.3 facing a camera at the origin looking along +x: depth = 0.3 everywhere
    cam = cam_at((0, 0, 0), (1, 0, 0), depth_noise_std=0.0)
    yz = rng.uniform(-0.2, 0.2, size=(20000, 2))
    pts = np.column_stack([np.full(len(yz), 0.3), yz])
    nrm = np.tile([-1.0, 0.0, 0.0], (len(pts), 1))
    cloud, pix = render(pts, nrm, cam, seed=0)
    assert len(cloud) > 1000
    q, uv = project(cloud, cam)
    np.testing.assert_allclose(q[:, 2], 0.3, **TOL["float64_ref"])
    # returned points are the surface samples themselves, in the pixel they project to
    np.testing.assert_allclose(np.floor(uv[:, ::-1] + 0.5), pix, **TOL["float64_exact"])
    img = depth_image(pts, nrm, cam, seed=0)
    np.testing.assert_allclose(img[np.isfinite(img)], 0.3, **TOL["float64_ref"])
    # flipped normals: the plane faces away, nothing is seen
    assert len(render(pts, -nrm, cam, seed=0)[0]) == 0


def test_sphere_front_side_only_with_exact_depths():
    c, R = np.array([0.5, 0.02, -0.01]), 0.1
    pts, nrm = fib_sphere(c, R, 60000)
    cam = cam_at((0, 0, 0), c, depth_noise_std=0.0)
    cloud, _ = render(pts, nrm, cam)
    assert len(cloud) > 500
    np.testing.assert_allclose(np.linalg.norm(cloud - c, axis=1), R, **TOL["float64_ref"])
    # each returned point is the first hit of its camera ray with the sphere (the near root)
    u = cloud / np.linalg.norm(cloud, axis=1, keepdims=True)
    b = u @ c
    t_near = b - np.sqrt(b * b - (c @ c - R * R))
    np.testing.assert_allclose(np.linalg.norm(cloud, axis=1), t_near, **TOL["float64_ref"])


def test_occluded_points_not_returned():
    # a small sphere hidden behind a large one along the optical axis
    big, small = (
        fib_sphere(np.array([0.4, 0, 0]), 0.05, 40000),
        fib_sphere(np.array([0.7, 0, 0]), 0.02, 20000),
    )
    pts = np.concatenate([big[0], small[0]])
    nrm = np.concatenate([big[1], small[1]])
    cam = cam_at((0, 0, 0), (1, 0, 0), depth_noise_std=0.0)
    idx, _ = visible_samples(pts, nrm, cam)
    assert len(idx) > 100
    assert np.all(idx < len(big[0]))  # nothing of the hidden sphere
    # shift the small sphere sideways out of the shadow: now it is seen
    pts2 = np.concatenate([big[0], small[0] + np.array([0, 0.25, 0])])
    idx2, _ = visible_samples(pts2, nrm, cam)
    assert np.any(idx2 >= len(big[0]))


def test_one_point_per_pixel():
    pts, nrm = fib_sphere(np.array([0.3, 0, 0]), 0.05, 50000)
    _, pix = visible_samples(pts, nrm, cam_at((0, 0, 0), (1, 0, 0)))
    lin = pix[:, 0] * 160 + pix[:, 1]
    assert len(np.unique(lin)) == len(lin)


def test_zbuffer_equals_naive_per_pixel_loop(rng):
    # oracle: for every pixel, the nearest facing in-frustum sample (first one on exact ties);
    # quantised depths force ties so the tie-break is exercised too
    cam = cam_at((0, 0, 0), (1, 0, 0), depth_noise_std=0.0)
    n = 6000
    pts = np.column_stack([np.round(rng.uniform(0.2, 0.4, n), 2), rng.uniform(-0.15, 0.15, (n, 2))])
    nrm = np.tile([-1.0, 0.0, 0.0], (n, 1))
    nrm[rng.random(n) < 0.2] *= -1.0  # some back-facing samples
    idx, pix = visible_samples(pts, nrm, cam)
    q, uv = project(pts, cam)
    best = {}
    for i in range(n):
        if nrm[i] @ (cam.c - pts[i]) <= 0:
            continue
        r, c = int(np.floor(uv[i, 1] + 0.5)), int(np.floor(uv[i, 0] + 0.5))
        if not (0 <= r < cam.height and 0 <= c < cam.width):
            continue
        if (r, c) not in best or q[i, 2] < q[best[(r, c)], 2]:
            best[(r, c)] = i
    keys = sorted(best, key=lambda rc: rc[0] * cam.width + rc[1])
    np.testing.assert_array_equal(idx, [best[k] for k in keys])
    np.testing.assert_array_equal(pix, np.array(keys))


def test_two_opposite_cameras_see_more_than_one():
    pts, nrm = fib_sphere(np.zeros(3), 0.05, 40000)
    a = cam_at((0.4, 0, 0), (0, 0, 0), depth_noise_std=0.0)
    b = cam_at((-0.4, 0, 0), (0, 0, 0), depth_noise_std=0.0)
    ia, _ = visible_samples(pts, nrm, a)
    ib, _ = visible_samples(pts, nrm, b)
    assert len(np.intersect1d(ia, ib)) == 0  # opposite hemispheres
    merged = capture(pts, nrm, (a, b), n_points=None, seed=0)
    assert len(merged) == len(ia) + len(ib)
    assert np.all(pts[ia][:, 0] > 0) and np.all(pts[ib][:, 0] < 0)


@pytest.mark.parametrize("sigma0, quad", [(0.001, 0.0), (0.0005, 0.01)])
def test_noise_along_ray_has_configured_std(sigma0, quad):
    # a plane facing the camera at depth 0.4; noise is along each ray
    cam = cam_at((0, 0, 0), (1, 0, 0), depth_noise_std=sigma0, depth_noise_quadratic=quad)
    g = np.linspace(-0.15, 0.15, 400)
    Y, Z = np.meshgrid(g, g)
    pts = np.column_stack([np.full(Y.size, 0.4), Y.ravel(), Z.ravel()])
    nrm = np.tile([-1.0, 0, 0], (len(pts), 1))
    idx, _ = visible_samples(pts, nrm, cam)
    cloud, _ = render(pts, nrm, cam, seed=3)
    clean = pts[idx]
    r_clean, r_noisy = np.linalg.norm(clean, axis=1), np.linalg.norm(cloud, axis=1)
    # direction unchanged
    np.testing.assert_allclose(
        cloud / r_noisy[:, None], clean / r_clean[:, None], **TOL["float64_ref"]
    )
    err = r_noisy - r_clean
    sigma = sigma0 + quad * 0.4**2
    n = len(err)
    assert n > 5000
    # sample std within 5 standard errors of sigma (se = sigma / sqrt(2 n)), mean within 5 se
    assert abs(err.std() - sigma) < 5 * sigma / np.sqrt(2 * n)
    assert abs(err.mean()) < 5 * sigma / np.sqrt(n)


def test_capture_downsamples_and_is_seeded():
    pts, nrm = fib_sphere(np.zeros(3), 0.05, 30000)
    cams = default_cameras(distance=0.3, height=0.0)
    a = capture(pts, nrm, cams, 512, seed=7)
    b = capture(pts, nrm, cams, 512, seed=7)
    c = capture(pts, nrm, cams, 512, seed=8)
    assert a.shape == (512, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_camera_roundtrip_and_bad_input():
    cam = default_cameras()[0]
    assert PinholeCamera.from_dict(cam.to_dict()) == cam
    with pytest.raises(InvalidInputError, match="rotation"):
        PinholeCamera((0, 0, 0), ((1, 0, 0), (0, 1, 0), (0, 0, 2)))
    with pytest.raises(InvalidInputError, match="fx"):
        PinholeCamera((0, 0, 0), ((1, 0, 0), (0, 1, 0), (0, 0, 1)), fx=-1.0)
    with pytest.raises(InvalidInputError, match="camera"):
        PinholeCamera.from_dict({**cam.to_dict(), "zoom": 2})
    with pytest.raises(InvalidInputError, match="up"):
        PinholeCamera.look_at((0, 0, 0), (0, 0, 1), up=(0, 0, 1))


def _identity_camera(**kw):
    return PinholeCamera((0.0, 0.0, 0.0), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), **kw)


@pytest.mark.parametrize(
    "field, value",
    [
        ("depth_noise_std", float("nan")),  # used to switch the noise off silently
        ("depth_noise_quadratic", float("inf")),
        ("cx", float("nan")),  # used to drop every point ("no camera sees the robot")
        ("cy", float("inf")),
        ("fx", float("inf")),
        ("width", 640.5),  # used to pass int() and fail later with a raw TypeError
        ("height", 0),
        ("width", "abc"),  # used to raise a raw ValueError from int()
        ("width", True),
        ("fy", "abc"),
        ("min_depth", float("nan")),
        ("max_depth", float("nan")),
    ],
)
def test_camera_fields_are_validated(field, value):
    with pytest.raises(InvalidInputError, match=field):
        _identity_camera(**{field: value})
    with pytest.raises(InvalidInputError, match=field):
        PinholeCamera.from_dict({**default_cameras()[0].to_dict(), field: value})


def test_camera_pixel_counts_normalised_to_int_and_far_limit_may_be_infinite():
    cam = _identity_camera(width=320.0, height=np.int64(240), max_depth=float("inf"))
    assert cam.width == 320 and type(cam.width) is int and type(cam.height) is int
    assert cam.max_depth == float("inf")


@pytest.mark.parametrize(
    "kw, field",
    [
        ({"hfov_deg": 0}, "hfov_deg"),
        ({"hfov_deg": 180.0}, "hfov_deg"),
        ({"hfov_deg": float("nan")}, "hfov_deg"),
        ({"vfov_deg": -5.0}, "vfov_deg"),
        ({"width": 640.5}, "width"),
        ({"height": "abc"}, "height"),
    ],
)
def test_look_at_checks_field_of_view_and_size(kw, field):
    # hfov_deg=0 used to raise ZeroDivisionError, 180 gave fx ~ 2e-14
    with pytest.raises(InvalidInputError, match=field):
        PinholeCamera.look_at((0.4, 0, 0.1), (0, 0, 0.1), **kw)


def test_capture_bad_input_is_a_clean_error():
    pts, nrm = fib_sphere(np.zeros(3), 0.05, 2000)
    cams = default_cameras(distance=0.3, height=0.0)
    for n in (-1, 0, 2.5, True):
        with pytest.raises(InvalidInputError, match="n_points"):
            capture(pts, nrm, cams, n, seed=0)
    with pytest.raises(InvalidInputError, match="points"):
        capture(pts[:, :2], nrm, cams, 16, seed=0)
    with pytest.raises(InvalidInputError, match="normals"):
        capture(pts, nrm[:10], cams, 16, seed=0)
    bad = pts.copy()
    bad[3] = np.nan  # used to report "no camera sees the robot"
    with pytest.raises(InvalidInputError, match="points: contains NaN"):
        capture(bad, nrm, cams, 16, seed=0)
    with pytest.raises(InvalidInputError, match="points"):
        render(bad, nrm, cams[0], 0)
    with pytest.raises(InvalidInputError, match="points"):
        visible_samples(bad, nrm, cams[0])
    for cams_bad in ([], 3, [cams[0], "x"]):
        with pytest.raises(InvalidInputError, match="cameras"):
            capture(pts, nrm, cams_bad, 16, seed=0)
    with pytest.raises(InvalidInputError, match="seed"):
        capture(pts, nrm, cams, 16, seed="abc")


def test_capture_accepts_a_generator_and_int_seeds_are_unchanged():
    pts, nrm = fib_sphere(np.zeros(3), 0.05, 30000)
    cams = default_cameras(distance=0.3, height=0.0)
    # int seeds: per-camera children of SeedSequence(seed), the last child picks the points
    children = np.random.SeedSequence(7).spawn(len(cams) + 1)
    cloud = np.concatenate(
        [render(pts, nrm, c, np.random.default_rng(ch))[0] for c, ch in zip(cams, children)]
    )
    ref = cloud[np.random.default_rng(children[-1]).choice(len(cloud), size=64, replace=False)]
    np.testing.assert_array_equal(capture(pts, nrm, cams, 64, seed=7), ref)
    # a Generator (used to raise TypeError): deterministic in its state, independent across calls
    g = np.random.default_rng(3)
    a, b = capture(pts, nrm, cams, 64, seed=g), capture(pts, nrm, cams, 64, seed=g)
    assert a.shape == (64, 3) and not np.array_equal(a, b)
    g2 = np.random.default_rng(3)
    np.testing.assert_array_equal(capture(pts, nrm, cams, 64, seed=g2), a)
    np.testing.assert_array_equal(capture(pts, nrm, cams, 64, seed=g2), b)
