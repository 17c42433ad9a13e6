"""Tissue scenario files: a TOML description of a needle or manipulation scene
(:func:`read_scenario_config`; :func:`riskplan.scenarios.registry.load_scenario_file` builds the scenario).

The format, key by key with units, is in docs/scenarios.md ("Scenario files"); the paper's
two scenes ship as ``riskplan/data/needle.toml`` and ``riskplan/data/manipulation.toml``
and load to configs equal to :class:`~riskplan.scenarios.needle.NeedleConfig` ``()`` and
:class:`~riskplan.scenarios.manipulation.ManipulationConfig` ``()``.

Every check runs on the file before any scenario is built: unknown keys (named with the
closest known one), missing fields, wrong types, and geometry outside the tissue raise
:class:`~riskplan.errors.InvalidInputError` naming the file and the field.
"""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from riskplan import geometry2d as geo
from riskplan._validation import check_count
from riskplan.errors import InvalidInputError
from riskplan.scenarios.tissue_files import _NO_HOLES, _needle_tissue, _read_tissue_mesh

__all__ = ["SHIPPED_SCENARIOS", "read_scenario_config", "shipped_path"]

#: Built-in scenario names and their shipped files (in ``riskplan/data``).
SHIPPED_SCENARIOS = {"needle": "needle.toml", "manipulation": "manipulation.toml"}

#: Length units a file may use and their factor to the scenario's length unit. ``unit``:
#: the paper's dimensionless lengths (kept as written); the others are converted to metres.
LENGTH_UNITS = {"unit": 1.0, "m": 1.0, "cm": 0.01, "mm": 0.001}
ANGLE_UNITS = ("rad", "deg")

_TOP = {"kind", "description", "units", "tissue", "material", "robot", "goal", "obstacles"}
_TOP_NEEDLE = _TOP | {"noise", "controls"}
_TOP_MANIP = _TOP | {"noise", "controls", "manipulators"}
_UNITS = {"length", "angle"}
_MATERIAL = {"youngs_modulus", "poissons_ratio", "plane"}
_OBSTACLE = {"polygon", "circle", "rectangle"}
_CIRCLE = {"center", "radius", "sides"}
_RECT = {"lo", "hi"}
_GOAL = {"center", "radius"}
_NEEDLE_TISSUE = {
    "width",
    "height",
    "outline",
    "mesh",
    "fixed_vertices",
    "fixed_edges",
    "fixed_region",
    "fixed_group",
    "holes",
}
_NEEDLE_ROBOT = {"start", "tau", "r_min"}
_NEEDLE_CONTROLS = {"v_max", "phi_max"}
_NEEDLE_NOISE = {"sensing_std", "actuation_std"}
_MANIP_TISSUE = {"outline", "mesh", "fixed_edge", "fixed", "target", "holes"}
_MANIP_MANIP = {"points", "patch_radius"}
_MANIP_CONTROLS = {"f_max", "df_max"}
_MANIP_NOISE = {"sensing_std", "actuation_std", "n_boundary"}
_MANIP_SOLVER = {"load_steps"}


def shipped_path(name: str) -> Path:
    """Path of the shipped scenario file of a built-in name (:data:`SHIPPED_SCENARIOS`).

    Parameters
    ----------
    name : str

    Returns
    -------
    pathlib.Path
    """
    if name not in SHIPPED_SCENARIOS:
        raise InvalidInputError(
            f"scenario: expected one of {', '.join(SHIPPED_SCENARIOS)}, got {name!r}"
        )
    return Path(str(resources.files("riskplan") / "data" / SHIPPED_SCENARIOS[name]))


class _Reader:
    """Typed access to one parsed file; every error names the file and the dotted field."""

    def __init__(self, path: Path, data: dict):
        self.path = path
        self.data = data
        self.length = 1.0
        self.deg = False

    def fail(self, field: str, msg: str):
        raise InvalidInputError(f"{self.path}: {field}: {msg}")

    def check_keys(self, table: dict, allowed: set, prefix: str) -> None:
        from riskplan.robots.params import suggest_key

        for k in table:
            if k not in allowed:
                full = f"{prefix}.{k}" if prefix else k
                raise InvalidInputError(
                    f"{self.path}: unknown key '{full}'{suggest_key(k, allowed)}"
                )

    def table(self, key: str, allowed: set, *, required: bool = True) -> dict:
        t = self.data.get(key)
        if t is None:
            if required:
                self.fail(key, "missing table")
            return {}
        if not isinstance(t, dict):
            self.fail(key, f"expected a table, got {type(t).__name__}")
        self.check_keys(t, allowed, key)
        return t

    def get(self, table: dict, prefix: str, key: str, default=None, *, required=False):
        if key not in table:
            if required:
                self.fail(f"{prefix}.{key}", "missing field")
            return default
        return table[key]

    def number(self, v, field: str, *, positive=False, nonneg=False) -> float:
        if isinstance(v, bool) or not isinstance(v, int | float):
            self.fail(field, f"expected a number, got {v!r}")
        v = float(v)
        if not math.isfinite(v):
            self.fail(field, f"must be finite, got {v!r}")
        if positive and v <= 0:
            self.fail(field, f"must be > 0, got {v!r}")
        if nonneg and v < 0:
            self.fail(field, f"must be >= 0, got {v!r}")
        return v

    def integer(self, v, field: str, low: int) -> int:
        return check_count(v, f"{self.path}: {field}", low)

    def length_(self, v, field: str, **kw) -> float:
        return self.number(v, field, **kw) * self.length

    def angle(self, v, field: str, **kw) -> float:
        a = self.number(v, field, **kw)
        return math.radians(a) if self.deg else a

    def points(self, v, field: str, n: int | None = None) -> np.ndarray:
        """``(k, 2)`` points of lengths (exactly ``n`` of them when ``n`` is given)."""
        if not isinstance(v, list) or not all(isinstance(p, list) and len(p) == 2 for p in v):
            self.fail(field, f"expected a list of [x, y] points, got {v!r}")
        pts = np.array(
            [[self.length_(c, f"{field}[{i}]") for c in p] for i, p in enumerate(v)],
            dtype=np.float64,
        ).reshape(-1, 2)
        if n is not None and len(pts) != n:
            self.fail(field, f"expected {n} points, got {len(pts)}")
        return pts

    def point(self, v, field: str) -> tuple[float, float]:
        if not isinstance(v, list) or len(v) != 2:
            self.fail(field, f"expected [x, y], got {v!r}")
        return (self.length_(v[0], field), self.length_(v[1], field))


def _read_units(r: _Reader) -> None:
    u = r.table("units", _UNITS, required=False)
    length = u.get("length", "unit")
    if length not in LENGTH_UNITS:
        r.fail("units.length", f"expected one of {', '.join(LENGTH_UNITS)}, got {length!r}")
    angle = u.get("angle", "rad")
    if angle not in ANGLE_UNITS:
        r.fail("units.angle", f"expected one of {', '.join(ANGLE_UNITS)}, got {angle!r}")
    r.length = LENGTH_UNITS[length]
    r.deg = angle == "deg"


def _read_material(r: _Reader, default_plane: str) -> dict:
    m = r.table("material", _MATERIAL)
    e = r.number(
        r.get(m, "material", "youngs_modulus", required=True),
        "material.youngs_modulus",
        positive=True,
    )
    nu = r.number(r.get(m, "material", "poissons_ratio", required=True), "material.poissons_ratio")
    if not -1.0 < nu < 0.5:
        r.fail("material.poissons_ratio", f"must lie in (-1, 0.5), got {nu!r}")
    plane = m.get("plane", default_plane)
    if plane not in ("stress", "strain"):
        r.fail("material.plane", f"expected 'stress' or 'strain', got {plane!r}")
    return {"youngs_modulus": e, "poissons_ratio": nu, "plane": plane}


def _read_goal(r: _Reader) -> dict:
    g = r.table("goal", _GOAL)
    center = r.point(r.get(g, "goal", "center", required=True), "goal.center")
    radius = r.length_(r.get(g, "goal", "radius", required=True), "goal.radius", positive=True)
    return {"goal_center": center, "goal_radius": radius}


def _read_obstacles(r: _Reader) -> list[tuple[str, np.ndarray]]:
    """``[(field, polygon (k, 2))]``: each ``[[obstacles]]`` entry holds exactly one of
    ``polygon`` (vertices), ``circle`` (``center``, ``radius``, ``sides``: a regular
    ``sides``-gon, :func:`riskplan.geometry2d.circle_polygon`) or ``rectangle`` (``lo``,
    ``hi`` corners)."""
    obs = r.data.get("obstacles", [])
    if not isinstance(obs, list):
        r.fail("obstacles", "expected an array of tables [[obstacles]]")
    out = []
    for i, o in enumerate(obs):
        f = f"obstacles[{i}]"
        if not isinstance(o, dict):
            r.fail(f, "expected a table")
        r.check_keys(o, _OBSTACLE, f)
        if len(o) != 1:
            r.fail(f, "expected exactly one of polygon, circle, rectangle")
        ((kind, v),) = o.items()
        if kind == "polygon":
            poly = r.points(v, f"{f}.polygon")
            if len(poly) < 3:
                r.fail(f"{f}.polygon", "need at least 3 vertices")
        elif kind == "circle":
            if not isinstance(v, dict):
                r.fail(f"{f}.circle", "expected a table {center, radius, sides}")
            r.check_keys(v, _CIRCLE, f"{f}.circle")
            c = r.point(r.get(v, f"{f}.circle", "center", required=True), f"{f}.circle.center")
            rad = r.length_(
                r.get(v, f"{f}.circle", "radius", required=True),
                f"{f}.circle.radius",
                positive=True,
            )
            sides = r.integer(v.get("sides", 20), f"{f}.circle.sides", 3)
            poly = geo.circle_polygon(c, rad, sides)
        else:
            if not isinstance(v, dict):
                r.fail(f"{f}.rectangle", "expected a table {lo, hi}")
            r.check_keys(v, _RECT, f"{f}.rectangle")
            lo = r.point(r.get(v, f"{f}.rectangle", "lo", required=True), f"{f}.rectangle.lo")
            hi = r.point(r.get(v, f"{f}.rectangle", "hi", required=True), f"{f}.rectangle.hi")
            if not (hi[0] > lo[0] and hi[1] > lo[1]):
                r.fail(f"{f}.rectangle", f"hi {hi} must exceed lo {lo} in x and y")
            poly = geo.rectangle_polygon(lo, hi)
        out.append((f, poly))
    return out


def _sensing_std(r: _Reader, noise: dict):
    """``noise.sensing_std`` (a length, > 0), or ``None`` where the file leaves it out."""
    sensing = noise.get("sensing_std")
    return None if sensing is None else r.length_(sensing, "noise.sensing_std", positive=True)


def _needle_config(r: _Reader):
    from riskplan.scenarios.needle import NeedleConfig

    r.check_keys(r.data, _TOP_NEEDLE, "")
    t = r.table("tissue", _NEEDLE_TISSUE)
    tissue = _needle_tissue(r, t)
    mat = _read_material(r, "stress")
    rob = r.table("robot", _NEEDLE_ROBOT)
    start = r.get(rob, "robot", "start", required=True)
    if not isinstance(start, list) or len(start) != 3:
        r.fail("robot.start", f"expected [x, y, heading], got {start!r}")
    start = (
        r.length_(start[0], "robot.start[0]"),
        r.length_(start[1], "robot.start[1]"),
        r.angle(start[2], "robot.start[2]"),
    )
    tau = r.number(r.get(rob, "robot", "tau", required=True), "robot.tau", positive=True)
    r_min = r.length_(r.get(rob, "robot", "r_min", required=True), "robot.r_min", positive=True)
    c = r.table("controls", _NEEDLE_CONTROLS)
    v_max = r.length_(r.get(c, "controls", "v_max", required=True), "controls.v_max", positive=True)
    phi_max = r.angle(
        r.get(c, "controls", "phi_max", required=True), "controls.phi_max", positive=True
    )
    if phi_max >= math.pi / 2:
        r.fail("controls.phi_max", f"must be below 90 degrees, got {math.degrees(phi_max)} degrees")
    n = r.table("noise", _NEEDLE_NOISE, required=False)
    sensing = _sensing_std(r, n)
    act = n.get("actuation_std")
    if act is not None:
        if not isinstance(act, list) or len(act) != 2:
            r.fail("noise.actuation_std", f"expected [speed std, steering std], got {act!r}")
        act = (
            r.length_(act[0], "noise.actuation_std[0]", nonneg=True),
            r.angle(act[1], "noise.actuation_std[1]", nonneg=True),
        )
    goal = _read_goal(r)
    obstacles = _read_obstacles(r)

    # geometry inside the tissue (material points of the reference rectangle or outline)
    def inside(p, field):
        p = np.atleast_2d(p)
        if "outline" in tissue:
            if not np.all(geo.points_in_polygon(p, tissue["outline"])):
                r.fail(field, "lies outside the tissue outline")
            return
        w, h = tissue["width"], tissue["height"]
        if np.any(p < 0.0) or np.any(p[:, 0] > w) or np.any(p[:, 1] > h):
            r.fail(field, f"lies outside the tissue [0, {w}] x [0, {h}]")

    inside(start[:2], "robot.start")
    gc, gr = goal["goal_center"], goal["goal_radius"]
    inside(geo.circle_polygon(gc, gr, 24), "goal")
    for f, poly in obstacles:
        inside(poly, f)
    return NeedleConfig(
        **tissue,
        start=start,
        obstacles=tuple(p for _, p in obstacles),
        v_max=v_max,
        phi_max=phi_max,
        tau=tau,
        r_min=r_min,
        sensing_std=sensing,
        actuation_std=act,
        **goal,
        **mat,
    )


def _segment_distance(p: np.ndarray, outline: np.ndarray) -> float:
    a, b = outline, np.roll(outline, -1, axis=0)
    ab = b - a
    t = np.clip(((p - a) * ab).sum(1) / (ab * ab).sum(1), 0.0, 1.0)
    return float(np.sqrt(((p - (a + t[:, None] * ab)) ** 2).sum(1)).min())


def _manipulation_config(r: _Reader):
    from riskplan.scenarios.manipulation import ManipulationConfig

    r.check_keys(r.data, _TOP_MANIP | {"solver"}, "")
    t = r.table("tissue", _MANIP_TISSUE)
    if "holes" in t:
        r.fail("tissue.holes", f"objects with holes are not supported: {_NO_HOLES['manipulation']}")
    if ("outline" in t) == ("mesh" in t):
        r.fail("tissue", "expected exactly one of outline, mesh")
    if "mesh" in t:
        outline, _ = _read_tissue_mesh(r, t["mesh"], "manipulation")
    else:
        outline = r.points(t["outline"], "tissue.outline")
    if len(outline) < 3:
        r.fail("tissue.outline", "need at least 3 vertices")
    if geo.polygon_area(outline) <= 0:
        r.fail("tissue.outline", "must be counter-clockwise with a positive area")
    if ("fixed_edge" in t) == ("fixed" in t):
        r.fail(
            "tissue", "expected exactly one of fixed_edge (an index), fixed (two outline vertices)"
        )
    if "fixed_edge" in t:
        fixed = r.integer(t["fixed_edge"], "tissue.fixed_edge", 0)
        if fixed >= len(outline):
            r.fail(
                "tissue.fixed_edge",
                f"expected an edge index in [0, {len(outline) - 1}], got {fixed}",
            )
    else:
        ends = r.points(t["fixed"], "tissue.fixed", 2)
        scale = float(np.max(outline.max(0) - outline.min(0)))
        near = [int(np.argmin(((outline - e) ** 2).sum(1))) for e in ends]
        if any(np.linalg.norm(outline[k] - e) > 1e-9 * scale for k, e in zip(near, ends)):
            r.fail("tissue.fixed", "both ends must be vertices of the outline")
        a, b = near
        n = len(outline)
        if (a + 1) % n == b:
            fixed = a
        elif (b + 1) % n == a:
            fixed = b
        else:
            r.fail("tissue.fixed", "the two vertices must be the ends of one outline edge")
    target = r.point(r.get(t, "tissue", "target", required=True), "tissue.target")
    if not geo.points_in_polygon(np.array([target]), outline)[0]:
        r.fail("tissue.target", "lies outside the tissue outline")
    mat = _read_material(r, "strain")
    m = r.table("manipulators", _MANIP_MANIP)
    pts = r.points(r.get(m, "manipulators", "points", required=True), "manipulators.points")
    if len(pts) < 1:
        r.fail("manipulators.points", "need at least one manipulator")
    scale = float(np.max(outline.max(0) - outline.min(0)))
    for i, p in enumerate(pts):
        if _segment_distance(p, outline) > 1e-9 * scale:
            r.fail(f"manipulators.points[{i}]", "must lie on the tissue outline")
    patch = r.length_(
        r.get(m, "manipulators", "patch_radius", required=True),
        "manipulators.patch_radius",
        positive=True,
    )
    c = r.table("controls", _MANIP_CONTROLS)
    f_max = r.number(r.get(c, "controls", "f_max", required=True), "controls.f_max", positive=True)
    df_max = r.number(
        r.get(c, "controls", "df_max", required=True), "controls.df_max", positive=True
    )
    n = r.table("noise", _MANIP_NOISE, required=False)
    sensing = _sensing_std(r, n)
    act = n.get("actuation_std")
    if act is not None:
        act = r.number(act, "noise.actuation_std", nonneg=True)
    n_boundary = r.integer(n.get("n_boundary", 12), "noise.n_boundary", 1)
    s = r.table("solver", _MANIP_SOLVER, required=False)
    load_steps = r.integer(s.get("load_steps", 1), "solver.load_steps", 1)
    goal = _read_goal(r)
    obstacles = _read_obstacles(r)
    if len(obstacles) != 1:
        r.fail(
            "obstacles",
            f"the manipulation scenario takes exactly one obstacle, got {len(obstacles)}",
        )
    f, obstacle = obstacles[0]
    if geo.polygons_intersect(outline, obstacle):
        r.fail(f, "overlaps the undeformed tissue (the obstacle must lie outside it)")
    return ManipulationConfig(
        outline=outline,
        fixed_edge=fixed,
        manipulators=pts,
        target=target,
        obstacle=obstacle,
        patch_radius=patch,
        n_boundary=n_boundary,
        f_max=f_max,
        df_max=df_max,
        sensing_std=sensing,
        actuation_std=act,
        load_steps=load_steps,
        **goal,
        **mat,
    )


def read_scenario_config(path) -> tuple[str, object]:
    """``(kind, config)`` of a scenario file.

    Lengths are multiplied by the factor of ``units.length`` (:data:`LENGTH_UNITS`), angles
    converted from degrees when ``units.angle = "deg"``. Raises
    :class:`~riskplan.errors.InvalidInputError` naming the file and the field.

    Parameters
    ----------
    path : str or path
        The TOML file.

    Returns
    -------
    tuple
        ``("needle", NeedleConfig)`` or ``("manipulation", ManipulationConfig)``.
    """
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"scenario: no such file {str(path)!r}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InvalidInputError(f"{path}: not a valid TOML file: {exc}") from exc
    r = _Reader(path, data)
    kind = data.get("kind")
    if kind is None:
        r.fail("kind", "missing field (needle | manipulation)")
    if kind not in SHIPPED_SCENARIOS:
        r.fail("kind", f"expected one of {', '.join(SHIPPED_SCENARIOS)}, got {kind!r}")
    desc = data.get("description", "")
    if not isinstance(desc, str):
        r.fail("description", f"expected a string, got {desc!r}")
    _read_units(r)
    try:
        cfg = _needle_config(r) if kind == "needle" else _manipulation_config(r)
    except InvalidInputError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise InvalidInputError(f"{path}: {exc}") from exc
    return kind, cfg
