"""Needle tissues that are not rectangles (riskplan.scenarios.files, NeedleConfig.outline):
an outline polygon or a mesh file with a named fixed boundary, planned and simulated end to
end; the FEM on an L-shaped and a circular domain against the closed form of uniform
pressure; the rectangle limit bit for bit; holes refused with the reason."""

from __future__ import annotations

import json

import numpy as np
import pytest

from riskplan import geometry2d as geo
from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import SimParams, rollout
from riskplan.scenarios.files import read_scenario_config
from riskplan.scenarios.needle import NeedleConfig, NeedleScenario
from riskplan.scenarios.registry import make_scenario
from tests.conftest import TOL

L_OUTLINE = [[0.0, 0.0], [1.0, 0.0], [1.0, 0.5], [0.5, 0.5], [0.5, 1.0], [0.0, 1.0]]

L_SCENE = """
kind = "needle"
description = "L-shaped tissue clamped along its bottom and left edges"

[units]
length = "unit"
angle = "deg"

[tissue]
outline = [[0.0, 0.0], [1.0, 0.0], [1.0, 0.5], [0.5, 0.5], [0.5, 1.0], [0.0, 1.0]]
fixed_edges = [0, 5]

[material]
youngs_modulus = 50.0
poissons_ratio = 0.4

[robot]
start = [0.05, 0.25, 0.0]
tau = 0.1
r_min = 0.25

[controls]
v_max = 0.5
phi_max = 60.0

[goal]
center = [0.85, 0.25]
radius = 0.07

[[obstacles]]
rectangle = { lo = [0.45, 0.05], hi = [0.55, 0.15] }
"""


def _scene(tmp_path, text=L_SCENE, name="l.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_l_shaped_scene_reads_with_its_fixed_edges(tmp_path):
    kind, cfg = read_scenario_config(_scene(tmp_path))
    assert kind == "needle"
    np.testing.assert_array_equal(cfg.outline, L_OUTLINE)
    assert (cfg.width, cfg.height) == (1.0, 1.0)  # the bounding box's extents
    sim = NeedleScenario(cfg)
    mesh = sim.mesh_data(120).mesh
    fixed = cfg.fixed_nodes(mesh)
    X = mesh.nodes[fixed]
    # exactly the nodes on the bottom (y = 0) and left (x = 0) edges
    on = np.isclose(mesh.nodes[:, 1], 0.0, **TOL["float64_exact"]) | np.isclose(
        mesh.nodes[:, 0], 0.0, **TOL["float64_exact"]
    )
    np.testing.assert_array_equal(fixed, np.flatnonzero(on))
    assert len(X) > 6  # more than the corners
    # the material point leaves the tissue in the L's missing quadrant
    st = sim.initial_state(SimParams(n_elements=120))
    assert sim.inside(st)
    out = type(st)._owned(
        0, np.zeros_like(st.displacement), 120, np.array([0.8, 0.8, 0.0]), np.array([0.8, 0.8, 0.0])
    )
    assert not sim.inside(out)
    # the planner's space: the L's box, less the missing quadrant
    space = sim.planning_space()
    assert space.contains(np.array([0.2, 0.8, 0.0])) and space.contains(np.array([0.8, 0.2, 1.0]))
    assert not space.contains(np.array([0.8, 0.8, 0.0]))


def test_l_shaped_scene_plans_and_simulates_end_to_end(tmp_path):
    """`plan tissue` and `tissue simulate` on the L-shaped file (tiny scale: 2 plans, 20
    checking runs), and the selected plan rolled out without noise stays in the tissue."""
    from typer.testing import CliRunner

    from riskplan.cli import app

    runner = CliRunner()
    scene = _scene(tmp_path)
    out = tmp_path / "plan"
    res = runner.invoke(
        app,
        ["plan", "tissue", "--scenario", str(scene), "--plans", "2", "--out", str(out)]
        + ["--workers", "1", "--check-runs", "20", "--check-others", "1", "--no-gif"],
    )
    assert res.exit_code == 0, res.output
    meta = json.loads((out / "selected.json").read_text())
    assert meta["n_candidates"] == 2 and 0.0 <= meta["p_success"] <= 1.0
    controls = np.loadtxt(out / "selected_controls.csv", delimiter=",", skiprows=1)
    sim = make_scenario(str(scene))
    params = sim.nominal_params
    states = rollout(sim, sim.initial_state(params), controls[:, 2:4], params)
    assert all(sim.inside(s) for s in states)
    assert not any(sim.in_collision(s) for s in states)
    sim_out = tmp_path / "sim"
    res = runner.invoke(
        app,
        ["tissue", "simulate", "--scenario", str(scene), "--out", str(sim_out)]
        + ["--steps", "4", "--max-frames", "2"],
    )
    assert res.exit_code == 0, res.output
    assert json.loads((sim_out / "summary.json").read_text())["steps"] == 4


def _pressure_check(cfg: NeedleConfig, n_elements: int, plane: str):
    """FEM of the scenario's mesh and fixed nodes under uniform pressure p on the whole
    boundary, the fixed nodes held at the exact displacement. Closed form on any domain:
    sigma = -p I, so u = eps X with eps = -(1 - nu) p / E (plane stress) or
    -(1 + nu)(1 - 2 nu) p / E (plane strain); P1 elements hold linear fields exactly."""
    from riskplan.deformable import LinearElasticModel, Material
    from riskplan.deformable.loads import traction_load

    E, nu, p = 50.0, 0.4, 0.3
    mesh = NeedleScenario(cfg).mesh_data(n_elements).mesh
    fixed = cfg.fixed_nodes(mesh)
    eps = -(1 - nu) * p / E if plane == "stress" else -(1 + nu) * (1 - 2 * nu) * p / E
    exact = eps * mesh.nodes
    model = LinearElasticModel(mesh, Material(E, nu, plane=plane), fixed)
    f = traction_load(mesh, lambda x, n: -p * n)
    u = model.solve(f, fixed_values=exact[np.sort(fixed)])
    return u, exact


@pytest.mark.parametrize("plane", ["stress", "strain"])
def test_fem_on_an_l_shaped_domain_matches_uniform_pressure(tmp_path, plane):
    _, cfg = read_scenario_config(_scene(tmp_path))
    u, exact = _pressure_check(cfg, 200, plane)
    np.testing.assert_allclose(u, exact, **TOL["float64_exact"])


def test_fem_on_a_circular_domain_matches_uniform_pressure():
    # a 40-gon disk held at two opposite vertices (the minimum that stops rigid motion)
    disk = geo.circle_polygon((0.5, 0.5), 0.45, 40)
    pins = np.stack([disk[[0, 0]], disk[[20, 20]]])
    cfg = NeedleConfig(
        outline=disk,
        fixed_segments=pins,
        start=(0.2, 0.5, 0.0),
        goal_center=(0.8, 0.5),
        obstacles=(),
    )
    assert len(cfg.fixed_nodes(NeedleScenario(cfg).mesh_data(150).mesh)) == 2
    u, exact = _pressure_check(cfg, 150, "stress")
    np.testing.assert_allclose(u, exact, **TOL["float64_exact"])


def test_rectangle_outline_is_the_paper_scene_bit_for_bit():
    """The rectangle limit: the unit square given as an outline (its vertices fixed, the
    default) gives the paper scene's states bit for bit."""
    paper = NeedleScenario(NeedleConfig())
    square = NeedleScenario(NeedleConfig(outline=geo.rectangle_polygon((0, 0), (1, 1))))
    params = SimParams(n_elements=175)
    u = np.tile([0.4, 0.3], (8, 1))
    a = rollout(paper, paper.initial_state(params), u, params)
    b = rollout(square, square.initial_state(params), u, params)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.pose, y.pose)
        np.testing.assert_array_equal(x.displacement, y.displacement)


def _gmsh_l(path, *, hole=False):
    """The L as a gmsh file written by meshio: a triangulated L, its boundary lines, and the
    physical group 'clamp' on the bottom edge's two lines (the L's bottom split at x = 0.5)."""
    meshio = pytest.importorskip("meshio")
    pts = np.array(
        [[0, 0], [0.5, 0], [1, 0], [1, 0.5], [0.5, 0.5], [0.5, 1], [0, 1], [0, 0.5]], float
    )
    tri = np.array([[0, 1, 4], [0, 4, 7], [1, 2, 3], [1, 3, 4], [7, 4, 5], [7, 5, 6]])
    if hole:  # drop the inner triangle pair around node 4: a second boundary loop
        pts = np.vstack([pts, [[0.25, 0.25], [0.75, 0.25], [0.25, 0.75]]])
    lines = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 6], [6, 7], [7, 0]])
    tags = np.array([1, 1, 2, 2, 2, 2, 2, 2])
    cells = [("triangle", tri), ("line", lines)]
    data = {
        "gmsh:physical": [np.full(len(tri), 3), tags],
        "gmsh:geometrical": [np.full(len(tri), 3), tags],
    }
    if hole:
        # a triangle fan around an inner void: the void's edges form a second boundary loop
        cells = [
            (
                "triangle",
                np.array(
                    [[0, 1, 8], [1, 9, 8], [1, 4, 9], [4, 10, 9], [4, 7, 10], [7, 8, 10], [7, 0, 8]]
                ),
            ),
            ("line", lines),
        ]
        data = {"gmsh:physical": [np.full(7, 3), tags], "gmsh:geometrical": [np.full(7, 3), tags]}
    m = meshio.Mesh(
        np.c_[pts, np.zeros(len(pts))],
        cells,
        cell_data=data,
        field_data={
            "clamp": np.array([1, 1]),
            "free": np.array([2, 1]),
            "tissue": np.array([3, 2]),
        },
    )
    meshio.write(path, m, file_format="gmsh22", binary=False)


def test_needle_tissue_from_a_gmsh_file_with_a_named_fixed_boundary(tmp_path):
    _gmsh_l(tmp_path / "l.msh")
    text = L_SCENE.replace(
        "outline = [[0.0, 0.0], [1.0, 0.0], [1.0, 0.5], [0.5, 0.5], [0.5, 1.0], [0.0, 1.0]]\nfixed_edges = [0, 5]",
        'mesh = "l.msh"\nfixed_group = "clamp"',
    )
    _, cfg = read_scenario_config(_scene(tmp_path, text))
    # the boundary loop of the file, counter-clockwise: the L with its split edges
    assert np.isclose(geo.polygon_area(cfg.outline), 0.75, **TOL["float64_exact"])
    assert len(cfg.outline) == 8
    mesh = NeedleScenario(cfg).mesh_data(120).mesh
    fixed = cfg.fixed_nodes(mesh)
    np.testing.assert_array_equal(
        fixed, np.flatnonzero(np.isclose(mesh.nodes[:, 1], 0.0, **TOL["float64_exact"]))
    )
    bad = text.replace('fixed_group = "clamp"', 'fixed_group = "clmp"')
    with pytest.raises(
        InvalidInputError, match=r"tissue.fixed_group: no group 'clmp'.*clamp, free"
    ):
        read_scenario_config(_scene(tmp_path, bad, "bad.toml"))


def test_holes_are_refused_with_the_reason(tmp_path):
    _gmsh_l(tmp_path / "h.msh", hole=True)
    text = L_SCENE.replace("fixed_edges = [0, 5]", "").replace(
        "outline = [[0.0, 0.0], [1.0, 0.0], [1.0, 0.5], [0.5, 0.5], [0.5, 1.0], [0.0, 1.0]]",
        'mesh = "h.msh"',
    )
    with pytest.raises(
        InvalidInputError, match=r"tissue.mesh: h.msh: .*holes .* not supported.*obstacle"
    ):
        read_scenario_config(_scene(tmp_path, text))
    with pytest.raises(
        InvalidInputError, match=r"tissue.holes: a tissue with holes is not supported"
    ):
        read_scenario_config(
            _scene(tmp_path, L_SCENE.replace("fixed_edges", "holes = []\nfixed_edges"))
        )
    from riskplan.scenarios.files import shipped_path

    manip = shipped_path("manipulation").read_text().replace("[tissue]", "[tissue]\nholes = []")
    with pytest.raises(InvalidInputError, match=r"tissue.holes: objects with holes .*sensed"):
        read_scenario_config(_scene(tmp_path, manip, "m.toml"))


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        (
            "fixed_edges = [0, 5]",
            "fixed_edges = [6]",
            r"tissue.fixed_edges\[0\]: expected an edge index",
        ),
        ("fixed_edges = [0, 5]", "fixed_vertices = [[0.0, 0.0]]", r"fewer than two distinct"),
        (
            "fixed_edges = [0, 5]",
            "fixed_vertices = [[0.1, 0.0]]",
            r"fixed_vertices\[0\]: must be a vertex",
        ),
        (
            "fixed_edges = [0, 5]",
            'fixed_group = "clamp"',
            r"fixed_group: names a group of the tissue.mesh",
        ),
        (
            "fixed_edges = [0, 5]",
            "width = 1.0",
            r"tissue: expected one of width/height, outline, mesh",
        ),
        ("center = [0.85, 0.25]", "center = [0.8, 0.8]", r"goal: lies outside the tissue outline"),
    ],
)
def test_bad_tissue_shapes_rejected(tmp_path, old, new, match):
    assert old in L_SCENE
    with pytest.raises(InvalidInputError, match=match):
        read_scenario_config(_scene(tmp_path, L_SCENE.replace(old, new)))


def test_fixed_region_fixes_the_boundary_nodes_inside_it(tmp_path):
    text = L_SCENE.replace(
        "fixed_edges = [0, 5]", "fixed_region = { lo = [-0.1, -0.1], hi = [0.3, 0.1] }"
    )
    _, cfg = read_scenario_config(_scene(tmp_path, text))
    mesh = NeedleScenario(cfg).mesh_data(120).mesh
    fixed = cfg.fixed_nodes(mesh)
    X = mesh.nodes[fixed]
    assert np.all(X[:, 0] <= 0.3) and np.all(X[:, 1] <= 0.1)
    assert set(fixed) <= set(mesh.boundary_nodes) and len(fixed) >= 2
