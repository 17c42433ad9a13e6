"""The simulated robot's body against obstacles: signed clearances of the tube around the
backbone (:func:`tube_clearance`) and of the separator disks (:func:`disk_clearance`), the
body-in-obstacle tests of :mod:`riskplan.planning.validate` (whose docstring gives the tube
test's Lipschitz refinement and its accuracy) and of the chest's plans."""

from __future__ import annotations

import math

import numpy as np

from riskplan._validation import as_array
from riskplan.collision import Environment
from riskplan.errors import InvalidInputError

__all__ = ["RESOLUTION", "disk_clearance", "tube_clearance"]

# default spacing of the refinement samples along ambiguous backbone chords (m)
RESOLUTION = 5e-4


def tube_clearance(
    environment: Environment, backbones, radius: float, *, resolution: float = RESOLUTION
) -> np.ndarray:
    r"""Signed clearance of a tube of ``radius`` around backbones (negative: the tube enters an obstacle).

    .. math:: c = \min_s \mathrm{sd}(x(s)) - r

    over the polyline, exact where it decides the sign up to ``resolution / 2``: ``sd`` at the
    ``n`` points, and at points ``resolution`` apart on the chords whose Lipschitz lower bound
    ``(sd_a + sd_b - h) / 2`` falls below ``radius`` (:mod:`riskplan.planning.validate`). Far
    from obstacles the value is the minimum over the ``n`` points only (an upper estimate,
    always positive there).

    Parameters
    ----------
    environment : Environment
        3-D obstacles in the backbones' frame.
    backbones : array_like, (..., n, 3)
        Backbone polylines (m).
    radius : float
        Tube radius ``r`` (m).
    resolution : float
        Sample spacing on refined chords (m).

    Returns
    -------
    numpy.ndarray, (...,)
        Clearance (m).
    """
    X = as_array(backbones, "backbones", min_ndim=2, last_dim=3)
    if not (np.isfinite(radius) and radius >= 0):
        raise InvalidInputError(f"radius: expected a finite length >= 0, got {radius!r}")
    if not (np.isfinite(resolution) and resolution > 0):
        raise InvalidInputError(f"resolution: expected a positive length, got {resolution!r}")
    shape, n = X.shape[:-2], X.shape[-2]
    X = X.reshape(-1, n, 3)
    sd = environment.signed_distance(X)  # (N, n)
    clear = sd.min(axis=1)
    if n > 1:
        h = np.linalg.norm(np.diff(X, axis=1), axis=-1)  # (N, n-1)
        lower = 0.5 * (sd[:, :-1] + sd[:, 1:] - h)
        amb = (lower < radius) & (clear[:, None] >= radius)
        i, j = np.nonzero(amb)
        if i.size:
            k = max(2, math.ceil(float(h[i, j].max()) / resolution))
            t = np.arange(1, k)[:, None] / k  # (k-1, 1)
            a, b = X[i, j], X[i, j + 1]  # (A, 3)
            pts = a[:, None, :] + t[None] * (b - a)[:, None, :]  # (A, k-1, 3)
            np.minimum.at(clear, i, environment.signed_distance(pts).min(axis=1))
    return (clear - radius).reshape(shape)


def disk_clearance(
    environment: Environment, s, positions, rotations, body, *, resolution: float = 1e-3
) -> np.ndarray:
    """Signed clearance of the separator disks of ``body`` (:class:`~riskplan.robots.geometry.BodyGeometry`)
    on backbones ``positions (..., n, 3)``, ``rotations (..., n, 3, 3)`` at arc lengths ``s (n,)``; ``(...,)`` [m].

    Each disk (radius ``R``, thickness ``t``, centred on the backbone at its arc length, plane
    normal to the body ``z`` axis) is taken as a flat disk of radius ``R - t/2`` swept by a ball
    of radius ``t/2`` (inside the true cylinder; only its rim corners, less than 0.3 t/2 deep, are
    left out). A disk whose centre is at least ``sqrt(R^2 + t^2/4) + resolution`` from every
    obstacle is clear (the value returned for it is the positive lower bound
    ``sd(centre) - sqrt(R^2 + t^2/4)``); otherwise the signed distance is evaluated on
    rings ``resolution`` apart over the flat disk and the clearance is ``min sd - t/2`` (negative:
    the disk enters an obstacle; penetrations shallower than about ``resolution / 2`` can be missed).

    Parameters
    ----------
    environment : Environment
        Obstacles in the robot's base frame.
    s : array_like, shape (n,)
        Arc lengths [m] of the backbone stations.
    positions : array_like, shape (..., n, 3)
        Backbone positions [m].
    rotations : array_like, shape (..., n, 3, 3)
        Backbone frames.
    body : BodyGeometry
        The disks' arc lengths, radius and thickness.
    resolution : float
        Ring spacing [m] of the evaluation over a disk.

    Returns
    -------
    numpy.ndarray
        ``(...,)`` least clearance [m] of a disk per backbone (negative: in collision).
    """
    from riskplan.robots.geometry import interpolate_frames

    P = np.asarray(positions, dtype=np.float64)
    shape = P.shape[:-2]
    n = P.shape[-2]
    P = P.reshape(-1, n, 3)
    Rm = np.asarray(rotations, dtype=np.float64).reshape(-1, n, 3, 3)
    ds = np.asarray(body.disk_s, dtype=np.float64)
    C, F = interpolate_frames(np.asarray(s, dtype=np.float64), P, Rm, ds)  # (N, D, 3), (N, D, 3, 3)
    half = 0.5 * body.disk_thickness
    enclosing = math.hypot(body.disk_radius, half)
    sd_c = environment.signed_distance(C)  # (N, D)
    clear = sd_c - enclosing
    near = np.nonzero(sd_c < enclosing + resolution)  # refined: also the values just above 0
    if near[0].size:
        rho_max = body.disk_radius - half
        k = max(1, math.ceil(rho_max / resolution))
        pts = [np.zeros(2)]
        for rho in rho_max * np.arange(1, k + 1) / k:
            m = max(6, math.ceil(2 * math.pi * rho / resolution))
            a = 2 * math.pi * np.arange(m) / m
            pts.extend(np.stack([rho * np.cos(a), rho * np.sin(a)], axis=-1))
        uv = np.asarray(pts)  # (Q, 2) in the disk plane
        Fn = F[near]  # (A, 3, 3)
        X = (
            C[near][:, None, :]
            + uv[None, :, 0, None] * Fn[:, None, :, 0]
            + uv[None, :, 1, None] * Fn[:, None, :, 1]
        )
        clear[near] = environment.signed_distance(X).min(axis=1) - half
    return clear.min(axis=1).reshape(shape)
