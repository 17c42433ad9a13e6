"""The configuration and full state of the needle scenario (:mod:`riskplan.scenarios.needle`,
paper section V-A): the tissue's outline and fixed boundary, obstacles and goal as material
points, the car's constants and the noise levels (:class:`NeedleConfig`), and the full state
``y`` (:class:`NeedleState`: material pose, world pose, tissue displacement)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from riskplan import geometry2d as geo
from riskplan._validation import as_array
from riskplan.errors import InvalidInputError
from riskplan.scenarios.values import SimState, check_material, frozen_array

__all__ = ["NeedleConfig", "NeedleState"]


@dataclass(frozen=True, eq=False)
class NeedleState(SimState):
    """Full state of the needle scenario.

    ``material (3,)`` = (X, Y, Θ): the robot's pose in the tissue's material frame (what the
    car kinematics move); ``displacement (n_nodes, 2)``: the tissue's response to the
    current push; ``pose (3,)`` = (x, y, θ): the world pose, ``X + u(X)`` and the heading
    of ``F t`` (a function of the other two, stored so it is computed once); the step index
    and the mesh size."""

    pose: np.ndarray = field(default_factory=lambda: np.zeros(3))
    material: np.ndarray | None = None

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "pose", frozen_array(self.pose))
        mat = self.pose if self.material is None else self.material
        object.__setattr__(self, "material", frozen_array(mat))

    @classmethod
    def _owned(cls, t: int, displacement: np.ndarray, n_elements: int, pose: np.ndarray, material):
        """The state of :meth:`NeedleScenario.step` without the defensive copies:
        ``displacement (n_nodes, 2)``, ``pose (3,)`` and ``material (3,)`` must be new
        C-contiguous float64 arrays that nothing else holds (made read-only here)."""
        displacement.setflags(write=False)
        pose.setflags(write=False)
        material.setflags(write=False)
        out = object.__new__(cls)
        out.__dict__.update(
            t=t, displacement=displacement, n_elements=n_elements, pose=pose, material=material
        )
        return out


def _default_obstacles():
    return (
        geo.circle_polygon((0.40, 0.71), 0.12, 20),
        geo.rectangle_polygon((0.55, 0.12), (0.68, 0.42)),
        geo.circle_polygon((0.25, 0.24), 0.08, 16),
    )


@dataclass(frozen=True, eq=False)
class NeedleConfig:
    """Geometry and constants of the needle scenario (paper V-A values by default).

    ``width``/``height``: the reference tissue ``[0, width] x [0, height]`` (the paper's
    unit square);
    ``outline``: or a tissue of any simple polygon ``(n, 2)`` of material points
    (counter-clockwise); ``width``/``height`` then become its bounding box's extents and
    :attr:`bounds` its box;
    ``fixed_segments``: ``(k, 2, 2)`` material segments whose mesh nodes are fixed (a
    zero-length segment fixes the node at its point); ``fixed_region``: ``(2, 2)`` box
    ``[lo, hi]`` whose boundary nodes are fixed. Both ``None`` (the paper): the outline's
    vertices (the square's four corners) are fixed. At least two distinct nodes must end up
    fixed (no rigid motion), checked when the mesh is made;
    ``obstacles``: polygons ``(k, 2)`` of material points (reference configuration);
    ``goal_center``/``goal_radius``: the goal disk (a 24-gon of material points);
    ``sensing_std``: standard deviation of each position measurement;
    ``actuation_std (2,)``: standard deviations of the actuation noise on ``(v, φ)``;
    ``youngs_modulus``/``poissons_ratio``: the nominal material (the planning parameters'
    E and ν when the scenario has no distribution).

    Noise that scales with the scene: left ``None``, the noise levels follow the paper's
    values scaled to this scene (docs/scenarios.md, "Scenario files")::

        actuation_std = (0.1 v_max, 5° · φ_max / 60°)
        sensing_std   = 0.01 · max(width, height)

    On the paper's scene (v_max = 0.5, φ_max = π/3, unit square) these are exactly
    ``(0.05, 5°)`` and ``0.01``; on a scene of 0.08 × 0.06 with v_max = 0.04 the speed
    noise is 0.004 (a fixed 0.05 would exceed the speed range, and the RRT's 2σ control
    margin would leave no speed to sample).
    """

    width: float = 1.0
    height: float = 1.0
    start: tuple[float, float, float] = (0.05, 0.45, 0.0)
    goal_center: tuple[float, float] = (0.85, 0.62)
    goal_radius: float = 0.07
    obstacles: tuple = field(default_factory=_default_obstacles)
    v_max: float = 0.5
    phi_max: float = math.pi / 3
    tau: float = 0.1
    r_min: float = 0.25
    sensing_std: float | None = None
    plane: str = "stress"
    actuation_std: tuple[float, float] | None = None
    youngs_modulus: float = 50.0
    poissons_ratio: float = 0.4
    outline: np.ndarray | None = None
    fixed_segments: np.ndarray | None = None
    fixed_region: np.ndarray | None = None

    def __post_init__(self):
        if self.outline is not None:
            poly = geo.check_simple_polygon(
                as_array(self.outline, "outline", shape=(None, 2)), "outline"
            )
            if geo.polygon_area(poly) <= 0:
                raise InvalidInputError("outline: must be counter-clockwise with a positive area")
            object.__setattr__(self, "outline", frozen_array(poly))
            ext = poly.max(0) - poly.min(0)
            object.__setattr__(self, "width", float(ext[0]))
            object.__setattr__(self, "height", float(ext[1]))
        if self.fixed_segments is not None:
            seg = as_array(self.fixed_segments, "fixed_segments", shape=(None, 2, 2))
            object.__setattr__(self, "fixed_segments", frozen_array(seg))
        if self.fixed_region is not None:
            box = as_array(self.fixed_region, "fixed_region", shape=(2, 2))
            if not np.all(box[1] >= box[0]):
                raise InvalidInputError(
                    f"fixed_region: hi must not be below lo, got {box.tolist()}"
                )
            object.__setattr__(self, "fixed_region", frozen_array(box))
        if self.sensing_std is None:
            object.__setattr__(
                self, "sensing_std", 0.01 * max(float(self.width), float(self.height))
            )
        if self.actuation_std is None:
            # the paper's (0.05, 5°) at v_max = 0.5, φ_max = π/3 (the ratio is exactly 1 there)
            std = (0.1 * float(self.v_max), math.radians(5.0) * (self.phi_max / (math.pi / 3)))
            object.__setattr__(self, "actuation_std", std)
        std = as_array(self.actuation_std, "actuation_std", shape=(2,))
        if not (np.all(np.isfinite(std)) and np.all(std >= 0.0)):
            raise InvalidInputError(f"actuation_std: must be finite and >= 0, got {std.tolist()}")
        object.__setattr__(self, "actuation_std", (float(std[0]), float(std[1])))
        check_material(self.youngs_modulus, self.poissons_ratio)
        for name in (
            "width",
            "height",
            "goal_radius",
            "v_max",
            "phi_max",
            "tau",
            "r_min",
            "sensing_std",
        ):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v <= 0:
                raise InvalidInputError(f"{name}: must be finite and > 0, got {v!r}")
        if self.phi_max >= math.pi / 2:
            raise InvalidInputError(f"phi_max: must be < pi/2, got {self.phi_max}")
        as_array(self.start, "start", shape=(3,))
        obs = tuple(
            frozen_array(as_array(p, f"obstacles[{i}]", shape=(None, 2)))
            for i, p in enumerate(self.obstacles)
        )
        object.__setattr__(self, "obstacles", obs)

    @property
    def corners(self) -> np.ndarray:
        """The reference tissue's polygon ``(n, 2)``: the outline, else the rectangle."""
        if self.outline is not None:
            return self.outline
        return geo.rectangle_polygon((0.0, 0.0), (self.width, self.height))

    @property
    def bounds(self) -> np.ndarray:
        """``(2, 2)`` ``[lo, hi]`` bounding box of the reference tissue."""
        if self.outline is not None:
            return np.stack([self.outline.min(0), self.outline.max(0)])
        return np.array([[0.0, 0.0], [float(self.width), float(self.height)]])

    def fixed_nodes(self, mesh) -> np.ndarray:
        """The fixed nodes of a mesh of the tissue.

        Parameters
        ----------
        mesh : TissueMesh
            A mesh of :attr:`corners`.

        Returns
        -------
        (F,) int array
            Sorted node indices: the outline's vertex nodes by default, else the nodes within
            ``1e-9`` of the tissue's extent of a ``fixed_segments`` entry and the boundary
            nodes inside ``fixed_region``. Raises :class:`InvalidInputError` when fewer than
            two nodes are fixed.
        """
        if self.fixed_segments is None and self.fixed_region is None:
            return mesh.vertex_nodes
        X = mesh.nodes
        tol = 1e-9 * float(np.ptp(self.corners, axis=0).max())
        keep = np.zeros(len(X), dtype=bool)
        if self.fixed_segments is not None and len(self.fixed_segments):
            seg = np.ascontiguousarray(self.fixed_segments.reshape(-1, 4))
            dist, _, _ = geo.closest_points_on_segments(seg, np.ascontiguousarray(X))
            keep |= dist <= tol
        if self.fixed_region is not None:
            b = mesh.boundary_nodes
            lo, hi = self.fixed_region
            inside = np.all((X[b] >= lo - tol) & (X[b] <= hi + tol), axis=1)
            keep[b[inside]] = True
        nodes = np.flatnonzero(keep)
        if len(nodes) < 2:
            raise InvalidInputError(
                f"fixed boundary: {len(nodes)} mesh node(s) fixed; at least two distinct nodes "
                "must be fixed so the tissue cannot move as a rigid body"
            )
        return nodes

    @property
    def goal_polygon(self) -> np.ndarray:
        """``(24, 2)`` the goal disk as a 24-gon of material points (reference configuration)."""
        return geo.circle_polygon(self.goal_center, self.goal_radius, 24)
