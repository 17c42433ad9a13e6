"""The needle's kinematics and planning space (:mod:`riskplan.scenarios.needle`, paper
section V-A): one Euler step of the paper's car (:func:`car_step`), the constant control that
steers it to a point (:func:`car_steer`, the simulator RRT's local steering rule), and the box
the RRT samples (``needle_box_space``), cut to a non-rectangular tissue's outline."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from riskplan import geometry2d as geo
from riskplan.scenarios.space import BoxSpace

__all__ = ["car_steer", "car_step"]


def car_step(pose, v, phi, *, tau: float = 0.1, r_min: float = 0.25, phi_max: float = math.pi / 3):
    """One Euler step of the paper's car (section V-A); batched over leading axes:

    .. math::

        x' = x + \\tau v \\cos\\theta, \\qquad y' = y + \\tau v \\sin\\theta, \\qquad
        \\theta' = \\theta + \\frac{\\tau v \\tan\\varphi}{r_{\\min} \\tan\\varphi_{\\max}}

    No validation (a hot path of the planners).

    Parameters
    ----------
    pose : array_like, shape (..., 3)
        ``(x, y, θ)``: position in scene units, heading in rad.
    v : float or array_like, shape (...)
        Speed (scene units per unit time).
    phi : float or array_like, shape (...)
        Steering angle φ in rad.
    tau : float, optional
        Time step τ.
    r_min : float, optional
        Turning radius at full steering ``|φ| = φ_max``.
    phi_max : float, optional
        Steering bound φ_max in rad.

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        The next pose, the broadcast of ``pose``, ``v`` and ``phi``.
    """
    if np.ndim(pose) == 1 and np.ndim(v) == 0 and np.ndim(phi) == 0:  # scalar fast path
        x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
        s = tau * float(v)
        return np.array(
            [
                x + s * math.cos(th),
                y + s * math.sin(th),
                th + s * math.tan(float(phi)) / (r_min * math.tan(phi_max)),
            ]
        )
    pose = np.asarray(pose, dtype=np.float64)
    th = pose[..., 2]
    out = np.empty(np.broadcast_shapes(pose.shape, np.shape(v) + (3,), np.shape(phi) + (3,)))
    out[..., 0] = pose[..., 0] + tau * v * np.cos(th)
    out[..., 1] = pose[..., 1] + tau * v * np.sin(th)
    out[..., 2] = th + tau * v * np.tan(phi) / (r_min * math.tan(phi_max))
    return out


def car_steer(
    pose,
    target,
    bounds,
    n_steps: int,
    *,
    tau: float = 0.1,
    r_min: float = 0.25,
    phi_max: float = math.pi / 3,
) -> np.ndarray:
    """A constant control ``(v, φ)`` inside ``bounds (2, 2)`` that drives the car of
    :func:`car_step` from ``pose (3,)`` to the point ``target[:2]`` in at most ``n_steps``
    steps, exactly where the bounds allow.

    Held for ``j`` steps, a constant control moves the car along chords of length
    ``s = τ v`` whose directions turn by ``Δ = s tan φ / (r_min tan φ_max)`` each step, so
    (a geometric sum) it ends at distance ``s |sin(jΔ/2) / sin(Δ/2)|`` in the direction
    ``θ + (j − 1) Δ/2``. Hitting a target at distance ``L`` and bearing ``α`` off the
    heading needs ``Δ = 2α / (j − 1)`` and ``s = L sin(Δ/2) / sin(jΔ/2)``; the fewest steps
    ``j ∈ [2, n_steps]`` whose ``(v, φ)`` lie in the bounds is used. If none does (the
    target too far, too near or too far off the heading): the steering of the circle
    through the target tangent to the heading (curvature ``2 sin α / L``, pure pursuit)
    and the speed that covers that arc (length ``L α / sin α``) in ``n_steps`` steps, each
    clipped to the bounds (the fastest speed for a target behind the car): the end of the
    edge gets as near the target as the bounds let it.

    Parameters
    ----------
    pose : array_like, shape (3,)
        Start ``(x, y, θ)``.
    target : array_like, shape (>= 2,)
        The point ``target[:2]`` to reach (a heading in ``target[2]`` is ignored).
    bounds : array_like, shape (2, 2)
        ``[[v_lo, v_hi], [φ_lo, φ_hi]]``.
    n_steps : int
        Most steps the control is held for.
    tau, r_min, phi_max : float, optional
        The car's constants (:func:`car_step`).

    Returns
    -------
    numpy.ndarray, shape (2,)
        The control ``(v, φ)``.
    """
    x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
    dx, dy = float(target[0]) - x, float(target[1]) - y
    dist = math.hypot(dx, dy)
    (v_lo, v_hi), (phi_lo, phi_hi) = (float(b) for b in bounds[0]), (float(b) for b in bounds[1])
    k = r_min * math.tan(phi_max)  # tan φ = k · (heading change per unit length)
    if dist == 0.0:
        return np.array([v_lo, min(max(0.0, phi_lo), phi_hi)])
    alpha = (math.atan2(dy, dx) - th + math.pi) % (2.0 * math.pi) - math.pi
    for j in range(2, int(n_steps) + 1):
        half = alpha / (j - 1)  # Δ/2
        s = dist / j if abs(half) < 1e-12 else dist * math.sin(half) / math.sin(j * half)
        if not s > 0.0:
            continue
        v, phi = s / tau, math.atan(k * 2.0 * half / s)
        if v_lo <= v <= v_hi and phi_lo <= phi <= phi_hi:
            return np.array([v, phi])
    phi = math.atan(k * 2.0 * math.sin(alpha) / dist)
    arc = dist if abs(alpha) < 1e-12 else dist * alpha / math.sin(alpha)
    v = min(max(arc / (n_steps * tau), v_lo), v_hi) if abs(alpha) < 0.5 * math.pi else v_hi
    return np.array([v, min(max(phi, phi_lo), phi_hi)])


@dataclass(frozen=True, eq=False)
class _OutlineSpace(BoxSpace):
    """The needle's :class:`BoxSpace` of a non-rectangular tissue: a state is valid when it
    lies in the box and its position in the reference ``outline (n, 2)`` (boundary
    included; the world position is judged, as the rectangle's box judges it)."""

    outline: np.ndarray | None = None

    def contains(self, x: np.ndarray) -> bool:
        return super().contains(x) and bool(
            geo.points_in_polygon(np.asarray(x[:2], dtype=np.float64)[None], self.outline)[0]
        )


def needle_box_space(cfg) -> BoxSpace:
    """The RRT's space of a needle configuration ``cfg`` (a
    :class:`~riskplan.scenarios.needle_config.NeedleConfig`; what
    :meth:`NeedleScenario.planning_space` hands the planner, documented there)."""
    (lo_x, lo_y), (hi_x, hi_y) = cfg.bounds
    space = (
        BoxSpace if cfg.outline is None else functools.partial(_OutlineSpace, outline=cfg.outline)
    )
    return space(
        low=[lo_x, lo_y, -math.pi],
        high=[hi_x, hi_y, math.pi],
        weights=[1.0, 1.0, cfg.r_min**2],
        periodic=[False, False, True],
        goal=[cfg.goal_center[0], cfg.goal_center[1], 0.0],
        steps_per_extension=3,
        steer=functools.partial(car_steer, tau=cfg.tau, r_min=cfg.r_min, phi_max=cfg.phi_max),
    )
