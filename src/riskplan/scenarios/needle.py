"""Scenario 1 of the deformable-planning paper (Patil, van den Berg & Alterovitz, RSS 2011,
section V-A): a car without reverse — a planar model of a bevel-tip steerable needle —
moving through a deformable unit square fixed at its four corners (or, from a scenario file,
a tissue of any outline with a named fixed boundary: :class:`NeedleConfig`). The paper: "the robot
traverses the deformable plane and pushes its surface forward"; the robot rides on the
tissue, so where the tissue goes, the robot goes.

Robot (paper V-A, Euler update with time step τ), **in the tissue's material frame**: the
material pose ``(X, Y, Θ)`` (reference coordinates of the material point the tip is at,
heading measured in the reference configuration) follows the paper's car::

    X_{t+1} = X_t + τ v_t cos Θ_t
    Y_{t+1} = Y_t + τ v_t sin Θ_t
    Θ_{t+1} = Θ_t + τ v_t tan φ_t / (r_min tan φ_max)

with ``v ∈ [0, v_max]``, ``φ ∈ [−φ_max, φ_max]``, ``v_max = 0.5``, ``φ_max = π/3``,
``τ = 0.1``, ``r_min = 0.25``; at ``|φ| = φ_max`` the curvature is ``1/r_min``. The tip
cuts its way through the material, so its kinematics hold relative to the material.

Tissue: isotropic linear elasticity (plane stress, unit thickness) on a triangle mesh of
the unit square with the four corner nodes fixed. After each step the robot pushes the
tissue with a force of magnitude ``f_int = params.force_scale`` (nominal 1) along its
direction of motion, ``f = f_int (cos Θ, sin Θ)``, applied as a point load at the
material point ``X`` under the robot (consistent nodal forces ``λ_a(X) f``); the
quasi-static displacement is ``u = K⁻¹ f``.

World pose (what is sensed and what meets the deformed obstacles and goal)::

    x = X + u(X)                      (P1 interpolation of the nodal displacement)
    θ = Θ

The heading the deformation would give, the direction of ``F t`` (``F = I + ∇u``
constant in the element holding X, ``t = (cos Θ, sin Θ)``; :func:`world_pose`), differs
from Θ by 0.012 rad on average and 0.055 rad at most at E = 50 (measured,
docs/scenarios.md), below one step's steering noise (5°), and the P1 gradient is
discontinuous across element edges: the heading would jump by up to that much whenever
the tip crosses an edge, a mesh artefact that the finite-difference linearisation turns
into spurious gains. So the world heading is taken as Θ. Obstacles and the goal region are embedded in the tissue: polygons
of material points whose current positions are ``X + u(X)``.

Modelling choices the paper leaves open (documented in docs/scenarios.md):

* the load and its direction are those of the reference configuration (small-strain
  linear elasticity: loads act on the reference body; the rotation between ``t`` and
  ``F t`` is second order in the load and is measured in docs/scenarios.md);
* the force is applied whatever the speed (the needle pushes whenever it is in the
  tissue; this keeps ``g`` smooth in ``v`` for numerical linearisation), and is zero
  once the robot has left the tissue (material point outside the reference square; world
  pose = material pose there);
* the tissue has no memory: the displacement is the response to the current push only.

Full state: material pose, displacement, step index; the world pose is a function of them
(kept in the state so that it is computed once). Sensing ``z = (x, y) + n``,
``n ~ N(0, σ² I)``: the world position, as the paper senses the robot.

Reduced state, two frames (``frame``; :meth:`NeedleScenario.with_frame`):

* ``"world"`` (default; the paper's formulation, used by the reproduction's figures):
  ``x = (x, y, θ)``, the world pose, what LQG-MP checks against the deformed obstacles;
  ``z = H x + n`` with the constant ``H = [I₂ 0]``. With the tissue carrying the robot,
  the world pose does not determine the next one (the deformation is hidden state), and
  the fitted ``A_t`` of :func:`riskplan.control.linearize` are ill-conditioned
  (docs/control.md, "Calibration").
* ``"material"`` (beyond the paper): ``x = (X, Y, Θ)``, the material pose. Its dynamics
  are the plain car above, whatever the tissue does; the tissue enters only the
  measurement, ``z = h(x; s) + n`` with ``h(X, Y, Θ; s) = X + u(X; Θ, s)``, whose Jacobian
  ``H_t = ∂h/∂x`` at the plan's pose is taken by central differences
  (:meth:`NeedleScenario.observation_jacobian`). Obstacles and goal are fixed sets of
  material points, so LQG-MP checks ``x`` against the reference polygons
  (:meth:`NeedleScenario.state_obstacles`): the world position is inside a deformed
  obstacle exactly when the material point is inside the reference one (the map
  ``X ↦ X + u(X)`` is one-to-one while no element inverts), up to the deformed polygon's
  edges being drawn straight between moved vertices.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from riskplan import geometry2d as geo
from riskplan._validation import as_array, as_generator, check_count
from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import (
    FEMScenario,
    SimParams,
    SimState,
    apply_actuation_noise,
    check_control,
    frozen_array,
    gaussian_noise,
)
from riskplan.scenarios.space import BoxSpace
from riskplan.scenarios.values import check_material

__all__ = [
    "FRAMES",
    "NeedleConfig",
    "NeedleScenario",
    "NeedleState",
    "car_steer",
    "car_step",
    "world_pose",
]


#: The reduced-state frames of :class:`NeedleScenario` (module docstring).
FRAMES = ("world", "material")

#: Step of the central differences of :meth:`NeedleScenario.observation_jacobian`, in
#: units of the scene size: far below an element (about 0.1 on the planning mesh), so a
#: difference straddles an element edge (where the P1 field has a kink) only for a pose
#: within 1e-6 of it.
H_STEP = 1e-6


def car_step(pose, v, phi, *, tau: float = 0.1, r_min: float = 0.25, phi_max: float = math.pi / 3):
    """One Euler step of the paper's car (section V-A); batched over leading axes.

    ``pose (..., 3)`` = (x, y, θ); ``v (...)``, ``phi (...)``. Returns ``(..., 3)``:
    ``(x + τ v cos θ, y + τ v sin θ, θ + τ v tan φ / (r_min tan φ_max))``. No validation.
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


def world_pose(material, u_element, lam, grad) -> np.ndarray:
    """The world pose ``(3,)`` of a material pose ``material (3,)`` = (X, Y, Θ) in a P1
    element with nodal displacements ``u_element (3, 2)``, barycentric weights ``lam (3,)``
    of ``X`` and shape-function gradients ``grad (3, 2)`` (``∇_X N_a``):

    .. math::

        x = X + \\sum_a \\lambda_a u_a, \\qquad
        F = I + \\sum_a u_a \\otimes \\nabla N_a, \\qquad
        \\theta = \\Theta + \\operatorname{atan2}(t \\times F t,\\; t \\cdot F t),
        \\quad t = (\\cos\\Theta, \\sin\\Theta).

    The heading is unwrapped about ``Θ`` (continuous along a path). No validation.
    """
    # plain floats: 3 x 2 numpy operations cost more than the arithmetic (planners' hot path)
    X, Y, th = np.asarray(material, dtype=np.float64).tolist()
    c, s = math.cos(th), math.sin(th)
    (u0x, u0y), (u1x, u1y), (u2x, u2y) = u_element.tolist()
    l0, l1, l2 = lam.tolist()
    (g0x, g0y), (g1x, g1y), (g2x, g2y) = grad.tolist()
    # directional derivative of u along t: (∇u) t = Σ_a u_a (∇N_a · t)
    d0, d1, d2 = g0x * c + g0y * s, g1x * c + g1y * s, g2x * c + g2y * s
    ftx = c + u0x * d0 + u1x * d1 + u2x * d2
    fty = s + u0y * d0 + u1y * d1 + u2y * d2
    dth = math.atan2(c * fty - s * ftx, c * ftx + s * fty)
    return np.array(
        [X + l0 * u0x + l1 * u1x + l2 * u2x, Y + l0 * u0y + l1 * u1y + l2 * u2y, th + dth]
    )


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
        return geo.circle_polygon(self.goal_center, self.goal_radius, 24)


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


class _MeshData:
    """Cached per element count: mesh, assembled stiffness parts (via a base model),
    point locator, and the interpolator of [obstacle vertices, goal polygon, goal centre]."""

    def __init__(self, cfg: NeedleConfig, n_elements: int):
        from riskplan.deformable import LinearElasticModel, Material, locate, mesh_polygon

        mesh = mesh_polygon(cfg.corners, n_elements)
        self.mesh = mesh
        self.base = LinearElasticModel(
            mesh, Material(50.0, 0.4, plane=cfg.plane), cfg.fixed_nodes(mesh)
        )
        self.locator = mesh.locator
        #: ``(n_elements, 3, 2)`` ∇_X of the P1 shape functions (the deformation gradient)
        self.shape_gradients = mesh.shape_gradients
        pts = np.concatenate(
            [*cfg.obstacles, cfg.goal_polygon, np.asarray(cfg.goal_center, dtype=np.float64)[None]]
        )
        self.interp = locate(mesh, pts)
        self.obstacle_slices = np.cumsum([0] + [len(p) for p in cfg.obstacles])
        k = int(self.obstacle_slices[-1])
        self.goal_slice = slice(k, k + 24)
        self.goal_center_index = k + 24


#: Free-DOF count up to which the dense flexibility matrix is kept (the planning mesh of
#: 175 elements has ~210); larger meshes solve with the sparse factorisation per step.
GREEN_MAX_DOFS = 700


class _NeedleModel:
    """Cached per ``(E, ν, n_elements)``: the linear FEM model and, for meshes with at
    most ``GREEN_MAX_DOFS`` free DOFs, its flexibility (Green's) matrix over all DOFs, so a
    point load costs a 6-row gather. Which path a model uses depends only on its mesh,
    so results never depend on the cache history."""

    def __init__(self, data: _MeshData, params: SimParams, plane: str):
        from riskplan.deformable import Material

        self.data = data
        self.model = data.base.with_material(
            Material(params.youngs_modulus, params.poissons_ratio, plane=plane)
        )
        n = 2 * data.mesh.n_nodes
        tri = data.mesh.triangles
        #: ``(n_elements, 6)`` flat DOFs of each element's nodes, x then y (the load gather)
        self.element_dofs = np.concatenate([2 * tri, 2 * tri + 1], axis=1)
        self.element_dofs.setflags(write=False)
        free = self.model.free_dofs
        self.n_dofs = n
        self.green = None
        if len(free) <= GREEN_MAX_DOFS:
            green = np.zeros((n, n))
            # K_ff⁻¹ on the free DOFs; a force at a fixed DOF is taken by the support.
            # Symmetric, so row k is the displacement response to a unit force at DOF k.
            green[np.ix_(free, free)] = self.model.solve_free(np.eye(len(free)))
            green.setflags(write=False)
            self.green = green

    def response(self, dofs: np.ndarray, vals: np.ndarray) -> np.ndarray:
        """Displacement ``(n_nodes, 2)`` for nodal force values ``vals`` at flat ``dofs``."""
        if self.green is not None:
            return (vals @ self.green[dofs]).reshape(-1, 2)
        f = np.zeros(self.n_dofs)
        np.add.at(f, dofs, vals)
        return self.model.solve_flat(f).reshape(-1, 2)


class NeedleScenario(FEMScenario):
    """The needle / car scenario as a :class:`~riskplan.scenarios.base.Simulator`.

    Parameters
    ----------
    config: :class:`NeedleConfig` (paper values by default).
    distribution: parameter distribution S used by :meth:`sample_params` (default: the
        nominal case, i.e. always ``nominal_params``).
    cache_size: FEM models kept (one per distinct ``(E, ν, n_elements)``).

    Dimensions: controls ``(v, φ)`` (q = 2), reduced state ``(x, y, θ)`` (p = 3),
    measurements ``(x, y)`` (2).
    """

    control_dim = 2
    state_dim = 3
    obs_dim = 2
    #: where the 2-D points of x are (LQG-MP, :mod:`riskplan.control.lqgmp`): the position
    collision_point_indices = ((0, 1),)
    #: the A-runs of :func:`riskplan.control.linearize` perturb the 2 controls: to first
    #: order they span 2 directions of x; the tissue's second-order response lifts X_t to
    #: full numerical rank with tiny singular values whose inverse gave LQR gains of 10^5
    a_max_rank = 2
    goal_point_indices = (0, 1)
    name = "needle"
    state_type = NeedleState

    def __init__(
        self,
        config: NeedleConfig | None = None,
        distribution=None,
        cache_size: int = 32,
        frame: str = "world",
    ):
        super().__init__(config or NeedleConfig(), distribution, cache_size)
        if frame not in FRAMES:
            raise InvalidInputError(f"frame: expected one of {FRAMES}, got {frame!r}")
        #: the reduced state's frame (module docstring): ``"world"`` (the paper's) or ``"material"``
        self.frame = frame
        self._bounds = np.array(
            [[0.0, self.config.v_max], [-self.config.phi_max, self.config.phi_max]]
        )
        self._bounds.setflags(write=False)
        H = np.zeros((2, 3))
        H[0, 0] = H[1, 1] = 1.0
        H.setflags(write=False)
        self.observation_matrix = H
        cov = self.config.sensing_std**2 * np.eye(2)
        cov.setflags(write=False)
        self.sensing_cov = cov

    @property
    def state_scale(self) -> np.ndarray:
        """``(3,)`` acceptable deviation of each reduced-state component, the scale of the
        LQR's default Bryson weights (:func:`riskplan.control.lqg_controller`): the goal
        radius for the position ``(x, y)``, and ``goal_radius / r_min`` for the heading
        (the heading change that, turned at the minimum radius, moves the tip by one goal
        radius)."""
        r = self.config.goal_radius
        return np.array([r, r, r / self.config.r_min])

    # ---- protocol ------------------------------------------------------------------
    @property
    def control_bounds(self) -> np.ndarray:
        """``[[0, v_max], [−φ_max, φ_max]]``."""
        return self._bounds

    def planning_space(self) -> BoxSpace:
        """The RRT's space (:class:`~riskplan.scenarios.space.PlanningScenario`).

        Returns
        -------
        BoxSpace
            The tissue's bounding box for ``(x, y)`` (the rectangle, or the outline's box:
            samples outside a non-rectangular outline leave the tissue, which the planner's
            state checks reject), the metric ``(x, y)`` plus ``r_min · θ``
            (a heading error of 1 rad counts like the arc the car needs to turn by it),
            3 steps per extension (at most 0.15 length units, about the goal disk's
            diameter) and :func:`car_steer` as the local steering rule.
        """
        cfg = self.config
        (lo_x, lo_y), (hi_x, hi_y) = cfg.bounds
        space = (
            BoxSpace
            if cfg.outline is None
            else functools.partial(_OutlineSpace, outline=cfg.outline)
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

    def actuation_cov(self) -> tuple:
        """The actuation covariance ``diag(σ_v², σ_φ²)`` of ``config.actuation_std`` (the
        paper scene: ``diag(0.05², (5°)²)``, :func:`riskplan.scenarios.uncertainty.needle_actuation_cov`)."""
        sv, sp = self.config.actuation_std
        return ((sv * sv, 0.0), (0.0, sp * sp))

    def _make_mesh_data(self, n_elements: int) -> _MeshData:
        return _MeshData(self.config, n_elements)

    def _make_model(self, params: SimParams) -> _NeedleModel:
        return _NeedleModel(self.mesh_data(params.n_elements), params, self.config.plane)

    def initial_state(self, params: SimParams | None = None, pose=None) -> NeedleState:
        """Robot at ``config.start`` (or the material pose ``pose (3,)``), undeformed
        tissue (world pose = material pose), ``t = 0``."""
        params = params or self.nominal_params
        d = self.mesh_data(params.n_elements)
        p = self.config.start if pose is None else pose
        p = as_array(p, "pose", shape=(3,))
        return NeedleState(
            t=0,
            displacement=np.zeros((d.mesh.n_nodes, 2)),
            n_elements=params.n_elements,
            pose=p,
            material=p,
        )

    def step(self, state: NeedleState, control, params: SimParams | None = None) -> NeedleState:
        """``y_{t+1} = g(y_t, u_t, s)`` (paper eq. 1 with the V-A car in the material frame
        and a linear FEM; module docstring).

        ``control (2,)`` = (v, φ) inside :attr:`control_bounds` (else
        :class:`InvalidInputError`). With actuation noise in ``params`` the applied
        control is ``clip(u + w_t)``. The material pose follows the car; the tissue
        displacement is the quasi-static response to ``f_int (cos Θ_{t+1}, sin Θ_{t+1})``
        at the new material point, and the world pose follows that displacement.
        """
        params = params or self.nominal_params
        self._check_state(state, params)
        u = check_control(control, self._bounds)
        u = apply_actuation_noise(u, params, state.t, self._bounds)
        cfg = self.config
        mat = car_step(
            state.material, u[0], u[1], tau=cfg.tau, r_min=cfg.r_min, phi_max=cfg.phi_max
        )
        disp, pose = self._tissue_response(mat, params)
        # new arrays: no defensive copies (a hot path of the planners)
        return NeedleState._owned(state.t + 1, disp, state.n_elements, pose, mat)

    def _tissue_response(self, mat: np.ndarray, params: SimParams):
        """New arrays ``(displacement (n_nodes, 2), world pose (3,))`` of the push at the
        material pose ``mat (3,)``."""
        m = self.model(params)
        d = m.data
        elem = -1
        if params.force_scale != 0.0:
            elem, lam = d.locator.locate(mat)  # reads mat[0], mat[1]
        if elem < 0:  # no push, or the robot has left the tissue: nothing moves it
            return np.zeros((d.mesh.n_nodes, 2)), mat.copy()
        th = float(mat[2])
        c, s = math.cos(th), math.sin(th)
        vals = np.empty(6)
        vals[:3] = lam * (params.force_scale * c)
        vals[3:] = lam * (params.force_scale * s)
        disp = m.response(m.element_dofs[elem], vals)
        pose = world_pose(mat, disp[d.mesh.triangles[elem]], lam, d.shape_gradients[elem])
        # heading: the material heading (module docstring: F's rotation is small, and the
        # P1 gradient jumps between elements, which finite differences would amplify)
        pose[2] = th
        return disp, pose

    def transfer_state(self, state: NeedleState, params: SimParams) -> NeedleState:
        """``state`` on the mesh of ``params``: the same material pose and step index, the
        displacement and world pose of its push recomputed there (undeformed at ``t = 0``).
        Lets :func:`riskplan.control.linearize` run mesh-size draws of ``M_t`` on their own
        meshes (the robot's world offset under the load depends on the mesh)."""
        if not isinstance(state, NeedleState):
            raise InvalidInputError(f"state: expected a NeedleState, got {type(state).__name__}")
        d = self.mesh_data(params.n_elements)
        mat = np.array(state.material)
        if state.t == 0:
            disp, pose = np.zeros((d.mesh.n_nodes, 2)), mat.copy()
        else:
            disp, pose = self._tissue_response(mat, params)
        return NeedleState._owned(state.t, disp, params.n_elements, pose, mat)

    def nodal_forces(self, state: NeedleState, params: SimParams | None = None) -> np.ndarray:
        """The consistent nodal forces ``(n_nodes, 2)`` the robot applies in ``state``
        (what ``state.displacement`` balances; for residual checks and plots)."""
        params = params or self.nominal_params
        self._check_state(state, params)
        d = self.mesh_data(state.n_elements)
        f = np.zeros((d.mesh.n_nodes, 2))
        if state.t == 0:
            return f  # the initial state is undeformed: the robot has not pushed yet
        elem, lam = d.locator.locate(state.material[:2])
        if elem >= 0 and params.force_scale > 0:
            th = state.material[2]
            dirn = params.force_scale * np.array([math.cos(th), math.sin(th)])
            f[d.mesh.triangles[elem]] += lam[:, None] * dirn[None]
        return f

    def with_frame(self, frame: str) -> NeedleScenario:
        """This scenario (same configuration, distribution and FEM caches) with the reduced
        state in ``frame`` (:data:`FRAMES`, module docstring). Simulation, collision and
        goal tests are the same in both frames; what changes is what the controller and
        LQG-MP see: :meth:`reduced`, :meth:`observation_jacobian`, :meth:`state_obstacles`
        and :meth:`state_goal`."""
        import copy

        if frame not in FRAMES:
            raise InvalidInputError(f"frame: expected one of {FRAMES}, got {frame!r}")
        out = copy.copy(self)
        out.frame = frame
        return out

    def reduced(self, state: NeedleState) -> np.ndarray:
        """``x``, a copy: the world pose ``(x, y, θ)`` (``frame="world"``) or the material
        pose ``(X, Y, Θ)`` (``frame="material"``)."""
        return np.array(state.pose if self.frame == "world" else state.material)

    def measure(self, state: NeedleState, noise=None, rng=None) -> np.ndarray:
        """``z = (x, y) + n``, the sensed world position of the robot in ``state`` (both
        frames; in the world frame equal to ``observe(reduced(state))``). ``noise (2,)``
        explicit, or drawn from ``N(0, σ² I)`` with ``rng``; zero if neither is given."""
        return np.array(state.pose[:2]) + gaussian_noise(self.sensing_cov, noise, rng, 2)

    def observation_jacobian(
        self, state: NeedleState, params: SimParams | None = None
    ) -> np.ndarray:
        """``H (2, 3)`` of the measurement at ``state`` with respect to the reduced state.

        World frame: the constant ``[I₂ 0]``. Material frame: ``H = ∂h/∂(X, Y, Θ)`` of
        ``h = X + u(X; Θ, s)`` (module docstring; ``s = params``, default the nominal), by
        central differences with step :data:`H_STEP`, the tissue's response recomputed at
        each perturbed material pose: ``u`` depends on the pose both through where the
        interpolation reads it and through where and in which direction the robot pushes.
        A robot outside the tissue (nothing moves it) has ``H = [I₂ 0]``.
        """
        if self.frame == "world":
            return np.array(self.observation_matrix)
        params = params or self.nominal_params
        mat = np.asarray(state.material, dtype=np.float64)
        H = np.zeros((2, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = H_STEP
            hi = self._tissue_response(mat + e, params)[1][:2]
            lo = self._tissue_response(mat - e, params)[1][:2]
            H[:, k] = (hi - lo) / (2.0 * H_STEP)
        return H

    def state_obstacles(self, state: NeedleState) -> list[np.ndarray]:
        """The obstacles in the reduced state's coordinates (what LQG-MP checks ``x``
        against): the deformed polygons of ``state`` (world frame, :meth:`obstacles`) or
        the reference polygons of material points (material frame)."""
        if self.frame == "world":
            return self.obstacles(state)
        return [np.array(p) for p in self.config.obstacles]

    def state_goal(self, state: NeedleState) -> np.ndarray:
        """The goal polygon ``(24, 2)`` in the reduced state's coordinates (world:
        :meth:`goal`; material: the reference goal disk's 24-gon)."""
        if self.frame == "world":
            return self.goal(state)
        return np.array(self.config.goal_polygon)

    def observe(self, x, noise=None, rng=None) -> np.ndarray:
        """``z = H x + n`` (paper eq. 3): position only, for the world frame's reduced state
        (in the material frame the measurement is not linear in ``x``: :meth:`measure`). ``noise (2,)`` given explicitly,
        or drawn from ``N(0, σ² I)`` with ``rng``; zero if neither is given."""
        x = as_array(x, "x", shape=(3,))
        return self.observation_matrix @ x + gaussian_noise(self.sensing_cov, noise, rng, 2)

    # ---- geometry of a state -----------------------------------------------------------
    def obstacles(self, state: NeedleState) -> list[np.ndarray]:
        """Deformed obstacle polygons ``[(k_i, 2)]`` in ``state``."""
        pts = self._points(state)
        s = self._data(state).obstacle_slices
        return [pts[s[i] : s[i + 1]] for i in range(len(s) - 1)]

    def goal(self, state: NeedleState) -> np.ndarray:
        """Deformed goal polygon ``(24, 2)``."""
        return self._points(state)[self._data(state).goal_slice]

    def goal_center(self, state: NeedleState) -> np.ndarray:
        """Current position ``(2,)`` of the material point at the goal's centre."""
        return self._points(state)[self._data(state).goal_center_index]

    def inside(self, state: NeedleState) -> bool:
        """Whether the robot is in the tissue: its material point lies in the reference
        square (or the reference outline, boundary included)."""
        x, y = state.material[0], state.material[1]
        if self.config.outline is not None:
            return bool(geo.points_in_polygon(np.array([[x, y]]), self.config.outline)[0])
        return bool(0.0 <= x <= self.config.width and 0.0 <= y <= self.config.height)

    def in_collision(self, state: NeedleState) -> bool:
        """Robot's world position inside a deformed obstacle."""
        p = state.pose[None, :2]
        x, y = float(p[0, 0]), float(p[0, 1])
        for poly in self.obstacles(state):
            lo, hi = poly.min(0), poly.max(0)
            if lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1] and geo.points_in_polygon(p, poly)[0]:
                return True
        return False

    def in_goal(self, state: NeedleState) -> bool:
        """Robot's world position inside the deformed goal polygon."""
        return bool(geo.points_in_polygon(state.pose[None, :2], self.goal(state))[0])

    def goal_distance(self, state: NeedleState) -> float:
        """Distance from the robot's world position to the (deformed) goal centre."""
        return float(np.linalg.norm(state.pose[:2] - self.goal_center(state)))

    def path(self, states) -> np.ndarray:
        """Robot world positions ``(T, 2)`` along a list of states."""
        return np.array([s.pose[:2] for s in states])

    def random_controls(self, n_steps: int, seed=None) -> np.ndarray:
        """``(n_steps, 2)`` random controls: speed in ``[0.6, 1] v_max``, steering a
        smoothed random walk inside the bounds (for demos and tests)."""
        n_steps = check_count(n_steps, "n_steps")
        gen = as_generator(seed)
        v = gen.uniform(0.6, 1.0, n_steps) * self.config.v_max
        phi = np.clip(np.cumsum(gen.normal(0.0, 0.25, n_steps)) * 0.5, -1, 1) * self.config.phi_max
        return np.stack([v, phi], axis=1)
