"""The configuration and full state of the manipulation scenario
(:mod:`riskplan.scenarios.manipulation`, paper section V-B): the object's outline and fixed
edge, the manipulators, target, goal and obstacle, the force and rate bounds and the noise
levels (:class:`ManipulationConfig`), and the full state ``y`` (:class:`ManipulationState`:
displacement and applied forces)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from riskplan import geometry2d as geo
from riskplan._validation import as_array
from riskplan.errors import InvalidInputError
from riskplan.scenarios.values import SimState, check_material, frozen_array

__all__ = ["ManipulationConfig", "ManipulationState"]


def _default_outline():
    return np.array([[0.0, 0.0], [0.7, 0.0], [1.0, 0.3], [1.0, 1.0], [0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class ManipulationConfig:
    """Geometry and constants of the manipulation scenario.

    ``outline (n, 2)``: the object (counter-clockwise); ``fixed_edge``: index ``i`` of the
    fixed edge ``outline[i] → outline[i+1]``; ``manipulators (3, 2)``: boundary points the
    forces act at; ``target (2,)``: internal target point; ``goal_center``/``goal_radius``:
    goal disk for the target (static, in the world frame); ``obstacle (k, 2)``: static
    polygon the object must not touch; ``n_boundary``: sensed boundary points, spread
    evenly by arc length over the free boundary; ``f_max``: bound of each applied force
    component (the manipulators saturate there); ``df_max``: bound of each force
    increment per step (the control), a quarter of ``f_max`` so that swinging a force from
    zero to its bound takes at least four steps (the rate limit the RRT used when controls
    were absolute forces: a quasi-static step jumps to the new equilibrium, and a larger
    jump would skip configurations the collision check never sees);
    ``sensing_std``: standard deviation of each boundary-point measurement, by default
    ``0.005 · (largest extent of the outline)`` (0.005 on the paper's unit object);
    ``actuation_std``: standard deviation of each force increment's actuation noise, by
    default ``0.1 df_max`` (:meth:`ManipulationScenario.actuation_cov`);
    ``youngs_modulus``/``poissons_ratio``: the nominal material.
    """

    outline: np.ndarray = field(default_factory=_default_outline)
    fixed_edge: int = 1
    manipulators: np.ndarray = field(
        default_factory=lambda: np.array([[0.0, 0.3], [0.0, 0.8], [0.5, 1.0]])
    )
    target: tuple[float, float] = (0.45, 0.5)
    goal_center: tuple[float, float] = (0.33, 0.3)
    goal_radius: float = 0.04
    obstacle: np.ndarray = field(default_factory=lambda: geo.circle_polygon((-0.25, 0.2), 0.07, 20))
    patch_radius: float = 0.1
    n_boundary: int = 12
    f_max: float = 1.5
    df_max: float = 0.375
    sensing_std: float | None = None
    plane: str = "strain"
    load_steps: int = 1
    actuation_std: float | None = None
    youngs_modulus: float = 50.0
    poissons_ratio: float = 0.4

    def __post_init__(self):
        outline = as_array(self.outline, "outline", shape=(None, 2))
        if len(outline) < 3:
            raise InvalidInputError("outline: need at least 3 vertices")
        if self.sensing_std is None:
            extent = float(np.max(outline.max(0) - outline.min(0)))
            object.__setattr__(self, "sensing_std", 0.005 * extent)
        if self.actuation_std is not None:
            a = float(self.actuation_std)
            if not (math.isfinite(a) and a >= 0.0):
                raise InvalidInputError(f"actuation_std: must be finite and >= 0, got {a!r}")
        check_material(self.youngs_modulus, self.poissons_ratio)
        object.__setattr__(self, "outline", frozen_array(outline))
        if not 0 <= int(self.fixed_edge) < len(outline):
            raise InvalidInputError(
                f"fixed_edge: expected an index in [0, {len(outline) - 1}], got {self.fixed_edge}"
            )
        object.__setattr__(
            self,
            "manipulators",
            frozen_array(as_array(self.manipulators, "manipulators", shape=(None, 2))),
        )
        object.__setattr__(
            self, "obstacle", frozen_array(as_array(self.obstacle, "obstacle", shape=(None, 2)))
        )
        as_array(self.target, "target", shape=(2,))
        as_array(self.goal_center, "goal_center", shape=(2,))
        for name in ("goal_radius", "patch_radius", "f_max", "df_max", "sensing_std"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v <= 0:
                raise InvalidInputError(f"{name}: must be finite and > 0, got {v!r}")
        if int(self.n_boundary) < 1:
            raise InvalidInputError(f"n_boundary: expected >= 1, got {self.n_boundary}")
        if geo.polygons_intersect(outline, self.obstacle):
            raise InvalidInputError("obstacle: overlaps the undeformed object")

    @property
    def fixed_segment(self) -> np.ndarray:
        """``(2, 2)`` the fixed edge ``outline[i] → outline[i+1]``, ``i = fixed_edge``."""
        i = int(self.fixed_edge)
        return np.stack([self.outline[i], self.outline[(i + 1) % len(self.outline)]])

    @property
    def goal_polygon(self) -> np.ndarray:
        """``(24, 2)`` the goal disk as a 24-gon (static, world frame)."""
        return geo.circle_polygon(self.goal_center, self.goal_radius, 24)

    def boundary_points(self) -> np.ndarray:
        """The sensed points, evenly spaced by arc length along the free boundary (the
        outline without the fixed edge), away from its ends: at arc lengths
        ``(k + 1/2) L / n_boundary``, ``k = 0 .. n_boundary − 1``, ``L`` the free length.

        Returns
        -------
        numpy.ndarray, shape (n_boundary, 2)
            Reference (material) positions.
        """
        n = len(self.outline)
        i0 = (int(self.fixed_edge) + 1) % n
        chain = np.array(
            [self.outline[(i0 + k) % n] for k in range(n)]
        )  # free part: chain[0] .. chain[n-1]
        seg = np.diff(chain, axis=0)
        length = np.sqrt((seg**2).sum(1))
        cum = np.concatenate([[0.0], np.cumsum(length)])
        s = (np.arange(self.n_boundary) + 0.5) / self.n_boundary * cum[-1]
        k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
        t = (s - cum[k]) / length[k]
        return chain[k] + t[:, None] * seg[k]


@dataclass(frozen=True, eq=False)
class ManipulationState(SimState):
    """Full state: FEM displacement, step index, mesh size and the applied forces
    ``forces (3, 2)`` (the sum of the scaled, noisy, saturated increments so far) that the
    displacement balances; the forces are part of the reduced state too."""

    forces: np.ndarray = field(default_factory=lambda: np.zeros((3, 2)))

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "forces", frozen_array(self.forces))
