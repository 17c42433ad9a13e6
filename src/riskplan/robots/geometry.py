"""Surface geometry of a tendon robot for simulated sensing (MDN paper section III, Fig. 3).

The body is the union of

* a backbone tube of radius ``r_b`` around the backbone curve, closed at the tip by a
  hemispherical cap (a capsule whose base end sits in the mount), and
* separator disks: cylinders of radius ``R`` and thickness ``t`` centred on the backbone at
  the disk arc lengths, with their axis along the body-frame ``z`` axis (the third column of
  the rotation, the backbone tangent for an unsheared rod).

Everything here is a pure array function of the backbone frames ``positions (..., n, 3)``
and ``rotations (..., n, 3, 3)`` (columns = body axes in the base frame), so it works on
any :class:`~riskplan.robots.RodShape` or on analytic curves in tests.

Surface points come with unit *outward* normals; the simulated cameras use the normals
to keep only surfaces facing them. Points of the tube that lie inside a disk, and disk
face points inside the tube (``rho < r_b``), are left out so the samples cover the outer
surface of the union only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan.errors import InvalidInputError


@dataclass(frozen=True)
class BodyGeometry:
    """Radii and disk placement of the sensed body (lengths in m).

    ``disk_s`` are the arc lengths of the disk centres; ``spacing`` is the target distance
    between neighbouring surface samples.
    """

    backbone_radius: float
    disk_radius: float
    disk_thickness: float
    disk_s: tuple[float, ...]
    spacing: float = 0.0005
    tip_cap: bool = True

    def __post_init__(self):
        for name in ("backbone_radius", "disk_radius", "disk_thickness", "spacing"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InvalidInputError(f"{name}: expected a positive length, got {v!r}")
        if self.disk_radius <= self.backbone_radius:
            raise InvalidInputError(
                f"disk_radius: expected > backbone_radius={self.backbone_radius}, got {self.disk_radius}"
            )

    @classmethod
    def from_params(cls, params, spacing: float = 0.0005) -> BodyGeometry:
        """Geometry of a robot described by :class:`riskplan.robots.params.RobotParams`."""
        bb, dk = params.backbone, params.disks
        return cls(
            backbone_radius=float(bb.outer_radius),
            disk_radius=float(dk.radius),
            disk_thickness=float(dk.thickness),
            disk_s=tuple(float(x) for x in dk.positions),
            spacing=float(spacing),
        )


def interpolate_frames(s, positions, rotations, s_new):
    """Backbone frames at arc lengths ``s_new (k,)`` from frames at ``s (n,)``.

    Positions by cubic Hermite interpolation with the body ``z`` axis (third rotation
    column) as tangent, ``dp/ds = R e3`` for a rod without shear or extension (the small
    strains of the Cosserat model change this by far less than a micrometre); rotations
    column-wise linearly, then projected back onto rotations (polar factor from the SVD).
    Exact at the nodes. Returns ``(..., k, 3)`` and ``(..., k, 3, 3)``.
    """
    s = np.asarray(s, dtype=np.float64)
    s_new = np.clip(np.asarray(s_new, dtype=np.float64), s[0], s[-1])
    j = np.clip(np.searchsorted(s, s_new, side="right") - 1, 0, len(s) - 2)
    h = s[j + 1] - s[j]
    w = (s_new - s[j]) / h
    w2, w3 = w * w, w * w * w
    h00, h10, h01, h11 = 2 * w3 - 3 * w2 + 1, w3 - 2 * w2 + w, -2 * w3 + 3 * w2, w3 - w2
    tang = rotations[..., 2]  # (..., n, 3) body z axes
    t0 = tang[..., j, :]
    t1 = tang[..., j + 1, :]
    P = (
        h00[:, None] * positions[..., j, :]
        + (h10 * h)[:, None] * t0
        + h01[:, None] * positions[..., j + 1, :]
        + (h11 * h)[:, None] * t1
    )
    Rl = (
        rotations[..., j, :, :] * (1 - w)[:, None, None]
        + rotations[..., j + 1, :, :] * w[:, None, None]
    )
    U, _, Vt = np.linalg.svd(Rl)
    R = U @ Vt
    return P, R


def _ring_angles(radius: float, spacing: float) -> np.ndarray:
    n = max(8, int(np.ceil(2 * np.pi * radius / spacing)))
    return 2 * np.pi * np.arange(n) / n


def sample_tube(s, positions, rotations, radius: float, spacing: float, *, exclude=()):
    """Points on a tube of ``radius`` around the backbone, with outward normals.

    ``p = x(s) + radius (cos phi d1(s) + sin phi d2(s))``, ``n = cos phi d1 + sin phi d2``,
    on a regular (s, phi) grid of about ``spacing``. ``exclude`` is a sequence of
    ``(s_lo, s_hi)`` intervals left out (the parts inside disks).
    Returns ``points (..., N, 3)`` and ``normals (..., N, 3)``.
    """
    s = np.asarray(s, dtype=np.float64)
    n_s = max(2, int(np.ceil((s[-1] - s[0]) / spacing)) + 1)
    ss = np.linspace(s[0], s[-1], n_s)
    keep = np.ones(n_s, dtype=bool)
    for lo, hi in exclude:
        keep &= ~((ss > lo) & (ss < hi))
    ss = ss[keep]
    P, R = interpolate_frames(s, positions, rotations, ss)
    phi = _ring_angles(radius, spacing)
    radial = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=-1)  # body frame (a, 3)
    N = radial @ np.swapaxes(R, -1, -2)[..., :, :, :]  # (..., k, a, 3): N[k, a] = R_k radial_a

    pts = P[..., :, None, :] + radius * N
    shp = pts.shape[:-3] + (-1, 3)
    return pts.reshape(shp), N.reshape(shp)


def sample_cap(position, rotation, radius: float, spacing: float, *, exclude_below: float = 0.0):
    """Hemisphere of ``radius`` closing the tube at a frame (``position (..., 3)``, ``rotation (..., 3, 3)``),
    bulging along +d3. Samples with axial height ``<= exclude_below`` (inside a disk at the tip)
    are left out. Returns points and outward normals ``(..., N, 3)``."""
    n_pol = max(2, int(np.ceil(0.5 * np.pi * radius / spacing)))
    dirs = [np.array([[0.0, 0.0, 1.0]])]  # the pole; the equator ring belongs to the tube
    for k in range(1, n_pol):
        pol = 0.5 * np.pi * k / n_pol  # polar angle from the tip direction d3
        phi = _ring_angles(radius * np.sin(pol), spacing)
        dirs.append(
            np.stack(
                [
                    np.sin(pol) * np.cos(phi),
                    np.sin(pol) * np.sin(phi),
                    np.full_like(phi, np.cos(pol)),
                ],
                -1,
            )
        )
    d = np.concatenate(dirs)  # body frame unit vectors (a, 3)
    d = d[radius * d[:, 2] > exclude_below]
    N = d @ np.swapaxes(rotation, -1, -2)
    return position[..., None, :] + radius * N, N


def sample_disk(
    position, rotation, radius: float, thickness: float, inner_radius: float, spacing: float
):
    """Closed cylinder (side + two annular faces ``inner_radius <= rho <= radius``) of a disk.

    The disk is centred at ``position (..., 3)`` with its axis along the third column of
    ``rotation (..., 3, 3)``. Returns points and outward normals ``(..., N, 3)``.
    """
    pts, nrm = [], []
    # side: rho = radius, h in [-t/2, t/2]
    phi = _ring_angles(radius, spacing)
    n_h = max(2, int(np.ceil(thickness / spacing)) + 1)
    h = np.linspace(-0.5 * thickness, 0.5 * thickness, n_h)
    cp, sp = np.cos(phi), np.sin(phi)
    side_n = np.stack([cp, sp, 0 * cp], -1)
    side_p = radius * side_n[None, :, :] + h[:, None, None] * np.array([0.0, 0.0, 1.0])
    pts.append(side_p.reshape(-1, 3))
    nrm.append(np.broadcast_to(side_n, side_p.shape).reshape(-1, 3))
    # faces: rings from inner_radius to radius (excluding the rim, which is on the side)
    n_r = max(1, int(np.ceil((radius - inner_radius) / spacing)))
    rings = inner_radius + (radius - inner_radius) * (np.arange(n_r) + 0.5) / n_r
    face = []
    for rho in rings:
        a = _ring_angles(rho, spacing)
        face.append(np.stack([rho * np.cos(a), rho * np.sin(a), np.zeros_like(a)], -1))
    face = np.concatenate(face)
    for sign in (1.0, -1.0):
        fp = face + np.array([0.0, 0.0, sign * 0.5 * thickness])
        pts.append(fp)
        nrm.append(np.broadcast_to(np.array([0.0, 0.0, sign]), fp.shape))
    P = np.concatenate(pts)
    Nb = np.concatenate(nrm)
    Rt = np.swapaxes(rotation, -1, -2)
    Pw = position[..., None, :] + P @ Rt
    Nw = Nb @ Rt
    return Pw, Nw


def sample_surface(s, positions, rotations, body: BodyGeometry):
    """Sample the whole body surface (tube + tip cap + disks) with outward unit normals.

    Parameters
    ----------
    s: ``(n,)`` arc lengths of the backbone frames (m).
    positions: ``(..., n, 3)`` backbone positions in the base frame (m).
    rotations: ``(..., n, 3, 3)`` body frames (columns d1, d2, d3 in the base frame).
    body: radii, disk arc lengths and sample spacing.

    Returns
    -------
    points ``(..., N, 3)`` and normals ``(..., N, 3)``; ``N`` depends only on ``s`` and
    ``body`` (not on the shape), so batches stack.
    """
    s = np.asarray(s, dtype=np.float64)
    positions = np.asarray(positions, dtype=np.float64)
    rotations = np.asarray(rotations, dtype=np.float64)
    if s.ndim != 1 or len(s) < 2 or np.any(np.diff(s) <= 0):
        raise InvalidInputError(
            f"s: expected strictly increasing arc lengths (n >= 2,), got shape {s.shape}"
        )
    n = len(s)
    if positions.shape[-2:] != (n, 3):
        raise InvalidInputError(f"positions: expected shape (..., {n}, 3), got {positions.shape}")
    if rotations.shape[-3:] != (n, 3, 3) or rotations.shape[:-3] != positions.shape[:-2]:
        raise InvalidInputError(
            f"rotations: expected shape {positions.shape[:-2] + (n, 3, 3)}, got {rotations.shape}"
        )
    if not (np.all(np.isfinite(positions)) and np.all(np.isfinite(rotations))):
        raise InvalidInputError("positions/rotations: contain NaN or inf")
    half = 0.5 * body.disk_thickness
    exclude = [(ds - half, ds + half) for ds in body.disk_s]
    parts_p, parts_n = [], []
    p, nv = sample_tube(
        s, positions, rotations, body.backbone_radius, body.spacing, exclude=exclude
    )
    parts_p.append(p)
    parts_n.append(nv)
    if body.tip_cap:
        L = s[-1]
        inside = [
            ds + half - L for ds in body.disk_s if ds - half < L < ds + half
        ]  # a disk at the tip
        p, nv = sample_cap(
            positions[..., -1, :],
            rotations[..., -1, :, :],
            body.backbone_radius,
            body.spacing,
            exclude_below=max(inside, default=0.0),
        )
        parts_p.append(p)
        parts_n.append(nv)
    if body.disk_s:
        Pd, Rd = interpolate_frames(s, positions, rotations, np.asarray(body.disk_s))
        p, nv = sample_disk(
            Pd, Rd, body.disk_radius, body.disk_thickness, body.backbone_radius, body.spacing
        )
        shp = p.shape[:-3] + (-1, 3)
        parts_p.append(p.reshape(shp))
        parts_n.append(nv.reshape(shp))
    return np.concatenate(parts_p, axis=-2), np.concatenate(parts_n, axis=-2)


def shape_surface(shape, body: BodyGeometry):
    """:func:`sample_surface` for a :class:`~riskplan.robots.RodShape` (``shape.s``, ``.positions``, ``.rotations``)."""
    return sample_surface(shape.s, shape.positions, shape.rotations, body)
