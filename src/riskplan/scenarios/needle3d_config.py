"""The 3-D needle's configuration and geometry: :class:`Needle3DConfig` (the block, start,
target, obstacles and constants), the full state :class:`Needle3DState`, and the per-mesh
layout of the tracked obstacle and target points. :mod:`riskplan.scenarios.needle3d` builds
the scenario on them and hands these names on."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from riskplan._validation import as_array
from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import SimState, frozen_array

__all__ = ["Needle3DConfig", "Needle3DState"]

_AXES = np.vstack([np.eye(3), -np.eye(3)])
_CORNERS = np.array(
    [[sx, sy, sz] for sx in (-1.0, 1.0) for sy in (-1.0, 1.0) for sz in (-1.0, 1.0)]
)


@dataclass(frozen=True, eq=False)
class Needle3DState(SimState):
    """Full state: ``material (12,)`` the tip's material pose vector (position, e₁, e₂, e₃);
    ``pose (12,)`` the world pose (position ``X + u(X)``, the material frame);
    ``displacement (k, 3)`` the displacement of the tracked material points (obstacle and
    target samples); ``applied (q,)`` the control applied in the step that led here (zero at
    ``t = 0``; the exact kinematic Jacobian of that step is :meth:`Needle3DScenario.a_prior`)."""

    pose: np.ndarray = field(default_factory=lambda: np.zeros(12))
    material: np.ndarray = field(default_factory=lambda: np.zeros(12))
    applied: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def __post_init__(self):
        super().__post_init__()
        for name in ("pose", "material", "applied"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))


def _obstacle_default():
    # a corridor along the line from the start to the target: two balls above and below it
    # and a box below its far half, 0.04 to 0.08 from the line
    return (
        ("sphere", (0.45, 0.36, 0.5), 0.1),
        ("box", (0.62, 0.3, 0.35), (0.74, 0.44, 0.65)),
        ("sphere", (0.42, 0.68, 0.56), 0.1),
    )


@dataclass(frozen=True, eq=False)
class Needle3DConfig:
    """Geometry and constants of the 3-D needle scenario.

    ``size (3,)``: the block ``[0, size]`` (bottom face ``z = 0`` fixed); ``start (3,)``,
    ``start_axis (3,)`` (e₃, the insertion direction) and ``start_bevel (3,)`` (e₁, the axis
    the needle bends about; made orthogonal to e₃); ``target_center``, ``target_radius``;
    ``obstacles``: ``("sphere", centre, radius)`` or ``("box", low, high)`` in material
    coordinates; ``v_max``, ``omega_max`` (rad per unit time), ``tau``, ``curvature`` κ
    (``1 / r``); ``duty_cycle``: a third control ρ ∈ [0, 1] scales the curvature;
    ``sensing_std`` and ``actuation_std`` (``None``: scaled to the scene, module docstring);
    ``youngs_modulus``, ``poissons_ratio``: the nominal material (the 2-D paper's E = 50,
    ν = 0.4).

    Why these defaults: the unit cube and E, ν, f_int of the 2-D paper scene; κ = 2 (a
    radius of half the block: the bevel needle turns by about a right angle across the
    block); ``ω_max = 10`` (one step turns the bevel by up to 1 rad, so spinning at
    ``ω_max`` gives a helix of radius ``κ / (κ² + (ω/v)²) ≈ 0.005`` at ``v = v_max``:
    practically straight).
    """

    size: tuple[float, float, float] = (1.0, 1.0, 1.0)
    start: tuple[float, float, float] = (0.05, 0.5, 0.5)
    start_axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    start_bevel: tuple[float, float, float] = (0.0, 0.0, 1.0)
    target_center: tuple[float, float, float] = (0.85, 0.55, 0.5)
    target_radius: float = 0.1
    obstacles: tuple = field(default_factory=_obstacle_default)
    v_max: float = 0.5
    omega_max: float = 10.0
    tau: float = 0.1
    curvature: float = 2.0
    duty_cycle: bool = False
    sensing_std: float | None = None
    actuation_std: tuple | None = None
    youngs_modulus: float = 50.0
    poissons_ratio: float = 0.4

    def __post_init__(self):
        size = as_array(self.size, "size", shape=(3,))
        if not np.all(size > 0) or not np.all(np.isfinite(size)):
            raise InvalidInputError(f"size: expected finite values > 0, got {size.tolist()}")
        for name in ("v_max", "omega_max", "tau", "curvature", "target_radius", "youngs_modulus"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise InvalidInputError(f"{name}: must be finite and > 0, got {v!r}")
        if not -1.0 < float(self.poissons_ratio) < 0.5:
            raise InvalidInputError(
                f"poissons_ratio: must lie in (-1, 0.5), got {self.poissons_ratio!r}"
            )
        if self.sensing_std is None:
            object.__setattr__(self, "sensing_std", 0.01 * float(size.max()))
        if not (math.isfinite(float(self.sensing_std)) and float(self.sensing_std) > 0):
            raise InvalidInputError(
                f"sensing_std: must be finite and > 0, got {self.sensing_std!r}"
            )
        q = 3 if self.duty_cycle else 2
        if self.actuation_std is None:
            std = (0.1 * self.v_max, 0.1 * self.omega_max, 0.1)[:q]
            object.__setattr__(self, "actuation_std", std)
        std = as_array(self.actuation_std, "actuation_std", shape=(q,))
        if not (np.all(np.isfinite(std)) and np.all(std >= 0)):
            raise InvalidInputError(f"actuation_std: must be finite and >= 0, got {std.tolist()}")
        object.__setattr__(self, "actuation_std", tuple(float(s) for s in std))
        start = as_array(self.start, "start", shape=(3,))
        if not (np.all(start >= 0) and np.all(start <= size)):
            raise InvalidInputError(f"start: {start.tolist()} lies outside the tissue block")
        tc = as_array(self.target_center, "target_center", shape=(3,))
        r = float(self.target_radius)
        if not (np.all(tc - r >= 0) and np.all(tc + r <= size)):
            raise InvalidInputError(
                f"target: the ball at {tc.tolist()} of radius {r} is not inside the tissue block"
            )
        e3 = as_array(self.start_axis, "start_axis", shape=(3,))
        e1 = as_array(self.start_bevel, "start_bevel", shape=(3,))
        if np.linalg.norm(e3) == 0 or np.linalg.norm(np.cross(e3, e1)) < 1e-9 * np.linalg.norm(e1):
            raise InvalidInputError("start_axis/start_bevel: expected two non-parallel vectors")
        obs = []
        for i, o in enumerate(self.obstacles):
            if not isinstance(o, (tuple, list)) or len(o) != 3 or o[0] not in ("sphere", "box"):
                raise InvalidInputError(
                    f"obstacles[{i}]: expected ('sphere', centre, radius) or ('box', low, high), got {o!r}"
                )
            if o[0] == "sphere":
                c = as_array(o[1], f"obstacles[{i}] centre", shape=(3,))
                rr = float(o[2])
                if not (math.isfinite(rr) and rr > 0):
                    raise InvalidInputError(f"obstacles[{i}]: radius must be > 0, got {o[2]!r}")
                lo, hi = c - rr, c + rr
                obs.append(("sphere", tuple(c.tolist()), rr))
            else:
                lo = as_array(o[1], f"obstacles[{i}] low", shape=(3,))
                hi = as_array(o[2], f"obstacles[{i}] high", shape=(3,))
                if not np.all(hi > lo):
                    raise InvalidInputError(f"obstacles[{i}]: high must exceed low")
                obs.append(("box", tuple(lo.tolist()), tuple(hi.tolist())))
            if not (np.all(lo >= 0) and np.all(hi <= size)):
                raise InvalidInputError(f"obstacles[{i}]: not inside the tissue block")
        object.__setattr__(self, "obstacles", tuple(obs))

    @property
    def start_frame(self) -> np.ndarray:
        """``R₀ (3, 3)`` = ``[e₁ e₂ e₃]`` from ``start_axis`` and ``start_bevel``."""
        e3 = np.asarray(self.start_axis, dtype=np.float64)
        e3 = e3 / np.linalg.norm(e3)
        e1 = np.asarray(self.start_bevel, dtype=np.float64)
        e1 = e1 - (e1 @ e3) * e3
        e1 /= np.linalg.norm(e1)
        return np.stack([e1, np.cross(e3, e1), e3], axis=1)

    def bodies(self):
        """``[(kind, centre (3,), A (3, 3))]`` of the obstacles then the target, and the
        sample offsets of each (the material points whose displacement fixes its affine
        image).

        Returns
        -------
        list of tuple
            ``(kind, centre (3,), A (3, 3), offsets (s, 3))`` per body.
        """
        out = []
        for o in self.obstacles:
            if o[0] == "sphere":
                c, r = np.asarray(o[1]), float(o[2])
                out.append(("ellipsoid", c, r * np.eye(3), r * _AXES))
            else:
                lo, hi = np.asarray(o[1]), np.asarray(o[2])
                h = 0.5 * (hi - lo)
                out.append(("box", 0.5 * (lo + hi), np.diag(h), _CORNERS * h))
        r = float(self.target_radius)
        out.append(("ellipsoid", np.asarray(self.target_center), r * np.eye(3), r * _AXES))
        return out


class _MeshData3D:
    """Per element count: the block and the layout of the tracked points."""

    def __init__(self, cfg: Needle3DConfig, n_elements: int):
        from riskplan.scenarios.tissue3d import TetBlock

        bodies = cfg.bodies()
        pts, self.slices = [], []
        for _, c, _, offs in bodies:
            k = len(pts)
            pts.append(c)
            pts.extend(c + offs)
            self.slices.append((k, len(pts)))
        self.kinds = [b[0] for b in bodies]
        self.centres = [b[1] for b in bodies]
        self.shapes = [b[2] for b in bodies]
        #: least-squares fit of ∇u from the samples: G = (pinv(offsets) Δu)ᵀ
        self.fit = [np.linalg.pinv(offs) for *_, offs in bodies]
        self.block = TetBlock(cfg.size, n_elements, np.array(pts))
