"""Procedural thoracic cavity for the chest-cavity planning experiment (MDN paper, Fig. 6).

The paper's mesh was segmented from a patient with a pleural effusion and is not public, so
this module builds a parameterised, seeded stand-in with the same parts:

* body wall — a hollow solid: outer ellipsoid plus an inverted inner ellipsoid (one obstacle
  with two shells), so the cavity inside it is free space;
* rib cage — closed tubes along the inner wall at regular heights, protruding a few
  millimetres into the cavity (ribs, costal cartilage and sternum as one loop per level);
* vertebral column — a vertical cylinder protruding from the posterior wall;
* lungs — two smooth, randomly perturbed ellipsoids, compressed upwards by the effusion;
* heart — a perturbed ellipsoid left of the midline, anterior;
* diaphragm — a dome (ellipsoid) closing the cavity from below;
* pleural space — the free gap between the lungs and the wall; at the base it widens into
  the effusion pocket between lungs/heart and diaphragm where the robot works;
* insertion point — on the outer body wall, laterally, between two ribs; the robot base
  frame sits ``port_depth`` inside the inner wall with its z axis along the insertion
  direction (medially), its x axis cranial.

Coordinates (metres, world frame): x to the patient's right (insertion side), y anterior,
z cranial, origin at the cavity centre. Dimensions are those of an adult thorax (inner
half-widths 15 x 11 cm, half-height 19 cm); the effusion pocket is sized so that the
paper robot (0.2 m, straight at home) is collision-free while bent configurations reach
the lungs, heart or diaphragm. All obstacle meshes are closed and outward-oriented.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np

from riskplan._validation import as_generator, check_count
from riskplan.errors import InvalidInputError


@dataclass(frozen=True)
class ChestParams:
    """Geometry of the procedural chest (metres). See the module docstring for the parts."""

    cavity_semi_axes: tuple[float, float, float] = (0.15, 0.11, 0.19)
    wall_thickness: float = 0.02
    # insertion (robot base) height and depth of the port inside the inner wall
    insertion_height: float = -0.05
    insertion_yaw: float = 0.0  # rotation of the insertion direction towards anterior (rad)
    port_depth: float = 0.015
    n_ribs: int = 8
    rib_spacing: float = 0.028
    rib_radius: float = 0.006
    rib_protrusion: float = 0.004
    spine_radius: float = 0.025
    spine_protrusion: float = 0.04
    # clearances of the effusion pocket above/below the insertion height
    lung_gap: float = 0.035
    heart_gap: float = 0.03
    diaphragm_gap: float = 0.04
    # relative amplitude of the smooth random shape variation of the organs
    shape_noise: float = 0.06
    subdivisions: int = 3
    rib_segments: int = 40
    rib_sides: int = 6

    def validate(self) -> None:
        import math
        import numbers
        from dataclasses import fields

        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "cavity_semi_axes":
                continue
            if f.name in ("n_ribs", "subdivisions", "rib_segments", "rib_sides"):
                check_count(v, f.name, None)
            elif isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
                raise InvalidInputError(f"{f.name}: expected a finite number, got {v!r}")
        try:
            a = np.asarray(self.cavity_semi_axes, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(
                f"cavity_semi_axes: expected three positive lengths, got {self.cavity_semi_axes!r}"
            ) from exc
        if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a <= 0):
            raise InvalidInputError(
                f"cavity_semi_axes: expected three positive lengths, got {self.cavity_semi_axes}"
            )
        for name in (
            "wall_thickness",
            "port_depth",
            "rib_spacing",
            "rib_radius",
            "spine_radius",
            "lung_gap",
            "heart_gap",
            "diaphragm_gap",
        ):
            if not getattr(self, name) > 0:
                raise InvalidInputError(f"{name}: expected > 0, got {getattr(self, name)}")
        if abs(self.insertion_height) >= 0.8 * a[2]:
            raise InvalidInputError(
                f"insertion_height: must lie within +-0.8 of the cavity half-height {a[2]}"
            )
        if not 0 <= self.shape_noise < 0.3:
            raise InvalidInputError(f"shape_noise: expected in [0, 0.3), got {self.shape_noise}")
        if not 1 <= self.subdivisions <= 5:
            raise InvalidInputError(f"subdivisions: expected 1..5, got {self.subdivisions}")
        if self.n_ribs < 0 or self.rib_segments < 8 or self.rib_sides < 3:
            raise InvalidInputError(
                "n_ribs >= 0, rib_segments >= 8 and rib_sides >= 3 are required"
            )


@dataclass
class Chest:
    """A built chest: obstacle meshes, the environment (world and robot-base frames) and the base frame."""

    params: ChestParams
    seed: int
    meshes: dict  # name -> trimesh.Trimesh (world frame)
    base_position: np.ndarray  # (3,) robot base origin, world frame
    base_rotation: np.ndarray  # (3, 3) columns = base x, y, z axes in the world frame
    insertion_point: np.ndarray  # (3,) on the outer body wall
    environment: object = field(repr=False)  # Environment, world frame
    base_environment: object = field(repr=False)  # Environment, robot base frame

    @property
    def n_triangles(self) -> int:
        return self.environment.n_faces

    def to_world(self, points_base) -> np.ndarray:
        """Base-frame points to world: ``p + R x``.

        Parameters
        ----------
        points_base : array_like, (..., 3)
            Points in the robot base frame (m).

        Returns
        -------
        numpy.ndarray, (..., 3)
            World points (m).
        """
        return self.base_position + np.asarray(points_base, dtype=np.float64) @ self.base_rotation.T

    def to_base(self, points_world) -> np.ndarray:
        """World points to the robot base frame: ``R^T (x - p)``.

        Parameters
        ----------
        points_world : array_like, (..., 3)
            World points (m).

        Returns
        -------
        numpy.ndarray, (..., 3)
            Base-frame points (m).
        """
        return (
            np.asarray(points_world, dtype=np.float64) - self.base_position
        ) @ self.base_rotation

    @property
    def base_pose(self):
        """The robot base in the world frame (:class:`riskplan.robots.BasePose`)."""
        from riskplan.collision.mesh_files import BasePose

        return BasePose(self.base_position, self.base_rotation)

    def save(self, path):
        """Write the chest as a world-frame mesh file with its sidecar.

        The sidecar ``<path>.json`` holds the frame, the robot base pose and :meth:`metadata`, so
        that :func:`riskplan.collision.mesh_files.load_environment` gives back
        :attr:`base_environment`.

        Parameters
        ----------
        path : str or path
            The mesh file; STL/OBJ/PLY by suffix.

        Returns
        -------
        pathlib.Path
            ``path``.
        """
        from riskplan.collision.mesh_files import save_environment

        return save_environment(
            self.environment, path, base_pose=self.base_pose, metadata=self.metadata()
        )

    def metadata(self) -> dict:
        """What the sidecar records to rebuild and place the chest.

        Returns
        -------
        dict
            ``seed``, ``params`` (the :class:`ChestParams` fields), ``triangles``,
            ``base_position (3,)``, ``base_rotation (3, 3)`` and ``insertion_point (3,)`` (m).
        """
        return {
            "seed": self.seed,
            "params": asdict(self.params),
            "triangles": self.n_triangles,
            "base_position": self.base_position.tolist(),
            "base_rotation": self.base_rotation.tolist(),
            "insertion_point": self.insertion_point.tolist(),
        }


def _ellipsoid(center, semi, subdivisions, rng=None, noise=0.0):
    """Closed ellipsoid mesh, optionally with a smooth random radial perturbation."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    n = np.asarray(m.vertices, dtype=np.float64)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    r = np.ones(len(n))
    if rng is not None and noise > 0:
        # sum of a few low-frequency plane waves on the sphere: smooth, star-shaped
        for _ in range(4):
            k = rng.normal(size=3)
            k *= rng.uniform(1.5, 3.0) / np.linalg.norm(k)
            r += noise / 4 * np.sin(n @ k + rng.uniform(0, 2 * np.pi))
    V = np.asarray(center, dtype=np.float64) + n * r[:, None] * np.asarray(semi, dtype=np.float64)
    return trimesh.Trimesh(V, np.asarray(m.faces), process=False)


def _tube_loop(curve, radius, sides):
    """Closed tube (torus topology) of radius ``radius`` around a closed planar horizontal curve ``(N, 3)``."""
    import trimesh

    N = len(curve)
    tang = np.roll(curve, -1, axis=0) - np.roll(curve, 1, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0])
    nrm = np.cross(tang, up)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    th = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.cos(th)[None, :, None] * nrm[:, None, :] + np.sin(th)[None, :, None] * up
    V = (curve[:, None, :] + radius * ring).reshape(-1, 3)
    faces = []
    for i in range(N):
        i2 = (i + 1) % N
        for j in range(sides):
            j2 = (j + 1) % sides
            a, b, c, d = i * sides + j, i2 * sides + j, i2 * sides + j2, i * sides + j2
            faces += [[a, b, c], [a, c, d]]
    m = trimesh.Trimesh(V, np.asarray(faces), process=False)
    if m.volume < 0:
        m.invert()
    return m


def build_chest(seed: int = 0, params: ChestParams | None = None, **overrides) -> Chest:
    """Build the procedural chest cavity; same ``seed`` and parameters give the same mesh.

    Parameters
    ----------
    seed : int
        Seed of the anatomy's random perturbations.
    params : ChestParams, optional
        Sizes and mesh resolution (default ``ChestParams()``).
    **overrides
        Fields of ``params`` to replace (e.g. ``subdivisions=4`` for a finer mesh).

    Returns
    -------
    Chest
        World-frame and base-frame environments, the robot base pose and the insertion point.
    """
    import trimesh

    from riskplan.collision import Environment
    from riskplan.collision.mesh_files import BasePose, environment_in_base_frame

    params = replace(params or ChestParams(), **overrides)
    params.validate()
    rng = as_generator(seed)
    A, B, C = params.cavity_semi_axes
    h = params.insertion_height
    sub = params.subdivisions
    noise = params.shape_noise
    meshes: dict[str, trimesh.Trimesh] = {}

    # body wall: outer shell + inverted inner shell = one hollow solid
    t = params.wall_thickness
    outer = _ellipsoid((0, 0, 0), (A + t, B + t, C + t), sub)
    inner = _ellipsoid((0, 0, 0), (A, B, C), sub)
    inner.invert()
    meshes["body_wall"] = trimesh.util.concatenate([outer, inner])

    # rib cage: horizontal loops centred just outside the inner wall, protruding into the cavity;
    # levels straddle the insertion height so the port is in an intercostal space
    k0 = -(params.n_ribs // 3)
    for i in range(params.n_ribs):
        z = h + (k0 + i + 0.5) * params.rib_spacing
        if abs(z) >= 0.95 * C:
            continue
        s = np.sqrt(1 - (z / C) ** 2)
        off = params.rib_radius - params.rib_protrusion
        phi = np.linspace(0, 2 * np.pi, params.rib_segments, endpoint=False)
        # offset along the ellipse normal (approximately: scale each semi-axis by the same margin)
        curve = np.column_stack(
            [(A * s + off) * np.cos(phi), (B * s + off) * np.sin(phi), np.full_like(phi, z)]
        )
        meshes[f"rib{i}"] = _tube_loop(curve, params.rib_radius, params.rib_sides)

    # vertebral column
    spine = trimesh.creation.cylinder(radius=params.spine_radius, height=2 * C, sections=32)
    spine.apply_translation([0.0, -B - params.spine_radius + params.spine_protrusion, 0.0])
    meshes["spine"] = spine

    # diaphragm dome: top at h - diaphragm_gap, bottom at the floor of the body wall, wide
    # enough to meet the wall all around (it seals the cavity from below)
    top = h - params.diaphragm_gap
    dsemi = (A * 1.05, B * 1.05, 0.5 * (top + C + t))
    meshes["diaphragm"] = _ellipsoid((0, 0, top - dsemi[2]), dsemi, sub, rng, noise * 0.3)

    # lungs (base at h + lung_gap), compressed upwards by the effusion
    base = h + params.lung_gap
    lung_top = 0.9 * C
    lz = (lung_top - base) / 2
    for name, side in (("lung_right", 1.0), ("lung_left", -1.0)):
        cx = side * 0.5 * A
        semi = (0.42 * A, 0.75 * B, lz)
        meshes[name] = _ellipsoid((cx, -0.05 * B, base + lz), semi, sub, rng, noise)
        # the perturbation moves the lowest point; shift so the base sits at the gap exactly
        m = meshes[name]
        m.apply_translation([0.0, 0.0, base - m.vertices[:, 2].min()])

    # heart: left of the midline, anterior, bottom at h + heart_gap
    hsemi = (0.36 * A, 0.42 * B, 0.28 * C)
    heart = _ellipsoid((-0.15 * A, 0.3 * B, 0.0), hsemi, sub, rng, noise)
    heart.apply_translation([0.0, 0.0, h + params.heart_gap - heart.vertices[:, 2].min()])
    meshes["heart"] = heart

    env = Environment.from_meshes(list(meshes.values()), names=list(meshes))

    # insertion: lateral (+x) wall at height h, direction medial, yawed towards anterior
    s = np.sqrt(1 - (h / C) ** 2)
    yaw = params.insertion_yaw
    direction = np.array([-np.cos(yaw), np.sin(yaw), 0.0])
    # wall point hit by the ray from the cavity axis against the insertion direction
    ray = -direction
    t_in = 1.0 / np.sqrt((ray[0] / (A * s)) ** 2 + (ray[1] / (B * s)) ** 2)
    s_out = np.sqrt(1 - (h / (C + params.wall_thickness)) ** 2)
    t_out = 1.0 / np.sqrt(
        (ray[0] / ((A + params.wall_thickness) * s_out)) ** 2
        + (ray[1] / ((B + params.wall_thickness) * s_out)) ** 2
    )
    inner_point = np.array([0.0, 0.0, h]) + t_in * ray
    insertion_point = np.array([0.0, 0.0, h]) + t_out * ray
    base_position = inner_point + params.port_depth * direction
    z_axis = direction
    x_axis = np.array([0.0, 0.0, 1.0])
    y_axis = np.cross(z_axis, x_axis)
    R = np.column_stack([x_axis, y_axis, z_axis])
    base_env = environment_in_base_frame(env, BasePose(base_position, R))
    return Chest(
        params=params,
        seed=seed,
        meshes=meshes,
        base_position=base_position,
        base_rotation=R,
        insertion_point=insertion_point,
        environment=env,
        base_environment=base_env,
    )


def chest_figure(chest: Chest, robot_points=None):
    """Matplotlib figure: exterior and interior views with the insertion point (Fig. 6 style).

    ``robot_points (N, 3)`` (world frame) are drawn as blue dots if given.
    """
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    colors = {
        "body_wall": (0.85, 0.7, 0.6, 0.08),
        "spine": (0.9, 0.9, 0.8, 0.6),
        "diaphragm": (0.7, 0.3, 0.3, 0.5),
        "lung_right": (0.9, 0.6, 0.65, 0.5),
        "lung_left": (0.9, 0.6, 0.65, 0.5),
        "heart": (0.7, 0.1, 0.1, 0.6),
    }
    fig = plt.figure(figsize=(11, 5))
    for k, (title, exterior) in enumerate((("exterior", True), ("interior", False))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        for name, m in chest.meshes.items():
            if exterior and name != "body_wall":
                continue
            col = colors.get(name, (0.95, 0.95, 0.9, 0.7))
            if exterior:
                col = (0.85, 0.7, 0.6, 0.35)
            tri = m.vertices[m.faces]
            ax.add_collection3d(
                Poly3DCollection(tri, facecolor=col, edgecolor=(0, 0, 0, 0.03), linewidth=0.1)
            )
        p = chest.insertion_point
        ax.scatter(*p, color="red", s=60)
        if robot_points is not None and not exterior:
            r = np.asarray(robot_points)
            ax.scatter(r[:, 0], r[:, 1], r[:, 2], s=1, color="blue")
        lim = np.abs(chest.environment.bounds).max()
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_zlim(-lim, lim)
        ax.set_box_aspect((1, 1, 1))
        ax.set_title(f"chest cavity ({title})")
        ax.set_xlabel("x (right) [m]")
        ax.set_ylabel("y (anterior) [m]")
        ax.set_zlabel("z (cranial) [m]")
        ax.view_init(elev=15, azim=30 if exterior else 60)
    return fig


def mesh_traces(meshes, wall_opacity: float = 0.15, opacity: float = 0.6) -> list:
    """Plotly ``Mesh3d`` traces of ``meshes`` (``{name: (vertices (n, 3), faces (m, 3))}``);
    the translucent ``body_wall`` gets ``wall_opacity`` so the organs inside stay visible."""
    import plotly.graph_objects as go

    return [
        go.Mesh3d(
            x=V[:, 0],
            y=V[:, 1],
            z=V[:, 2],
            i=F[:, 0],
            j=F[:, 1],
            k=F[:, 2],
            name=name,
            opacity=wall_opacity if name == "body_wall" else opacity,
            showlegend=True,
        )
        for name, (V, F) in meshes.items()
    ]


def chest_plotly(chest: Chest, robot_points=None):
    """Interactive plotly figure of all obstacles (and optional robot points, world frame)."""
    import plotly.graph_objects as go

    data = mesh_traces({name: (m.vertices, m.faces) for name, m in chest.meshes.items()})
    p = chest.insertion_point
    data.append(
        go.Scatter3d(
            x=[p[0]],
            y=[p[1]],
            z=[p[2]],
            mode="markers",
            marker=dict(size=6, color="red"),
            name="insertion",
        )
    )
    if robot_points is not None:
        r = np.asarray(robot_points)
        data.append(
            go.Scatter3d(
                x=r[:, 0],
                y=r[:, 1],
                z=r[:, 2],
                mode="markers",
                marker=dict(size=1.5, color="blue"),
                name="robot",
            )
        )
    fig = go.Figure(data=data)
    fig.update_layout(scene=dict(aspectmode="data"), title="procedural chest cavity")
    return fig
