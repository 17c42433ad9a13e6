"""Tissue scenario files (riskplan.scenarios.files): the shipped files are the paper's
scenes exactly, a small custom needle scene plans, bad files are rejected before any work."""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
import pytest

from riskplan import geometry2d as geo
from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import SimParams
from riskplan.scenarios.files import read_scenario_config, shipped_path
from riskplan.scenarios.manipulation import ManipulationConfig, ManipulationScenario
from riskplan.scenarios.needle import NeedleConfig, NeedleScenario
from riskplan.scenarios.registry import make_scenario
from riskplan.scenarios.uncertainty import NEEDLE_ACTUATION_STD, needle_actuation_cov
from tests.conftest import TOL

TOL_EXACT = TOL["float64_exact"]


def _same(a, b) -> bool:
    """Field values equal bit for bit (arrays, tuples of arrays, scalars)."""
    if isinstance(a, tuple) and a and isinstance(a[0], np.ndarray):
        return len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(a, b)
    return type(a) is type(b) and a == b


@pytest.mark.parametrize(
    ("name", "cls"), [("needle", NeedleConfig), ("manipulation", ManipulationConfig)]
)
def test_shipped_files_are_the_paper_scenarios(name, cls):
    kind, cfg = read_scenario_config(shipped_path(name))
    assert kind == name
    default = cls()
    diff = [
        f.name for f in fields(cls) if not _same(getattr(cfg, f.name), getattr(default, f.name))
    ]
    assert diff == []


def test_paper_needle_noise_unchanged_by_the_scaling_rule():
    sim = make_scenario("needle", "actuation")
    assert sim.config.actuation_std == NEEDLE_ACTUATION_STD
    assert sim.config.sensing_std == 0.01
    assert sim.actuation_cov() == needle_actuation_cov()
    assert sim.distribution.cov == needle_actuation_cov()
    from_file = make_scenario(str(shipped_path("needle")), "actuation")
    assert from_file.distribution.cov == sim.distribution.cov
    assert from_file.nominal_params == sim.nominal_params


def test_needle_noise_scales_with_the_controls():
    cfg = NeedleConfig(
        width=0.08,
        height=0.06,
        v_max=0.04,
        phi_max=math.pi / 6,
        r_min=0.02,
        start=(0.004, 0.03, 0.0),
        goal_center=(0.06, 0.036),
        goal_radius=0.006,
        obstacles=(),
    )
    sv, sp = cfg.actuation_std
    assert np.isclose(sv, 0.1 * 0.04, **TOL_EXACT)
    assert np.isclose(sp, math.radians(2.5), **TOL_EXACT)
    assert np.isclose(cfg.sensing_std, 0.01 * 0.08, **TOL_EXACT)


SMALL = """
kind = "needle"
[units]
length = "mm"
angle = "deg"
[tissue]
width = 80.0
height = 60.0
[material]
youngs_modulus = 50.0
poissons_ratio = 0.4
[robot]
start = [4.0, 30.0, 0.0]
tau = 0.1
r_min = 20.0
[controls]
v_max = 40.0
phi_max = 60.0
[goal]
center = [60.0, 36.0]
radius = 6.0
[[obstacles]]
rectangle = { lo = [30.0, 5.0], hi = [40.0, 25.0] }
"""


def test_small_custom_needle_scene_plans(tmp_path):
    """The 0.08 x 0.06 scene with v_max = 0.04: a fixed speed noise of 0.05 left no speed
    inside the RRT's 2-sigma margin; scaled to 0.004 it plans, and its plans reach the goal
    without collision when executed without noise."""
    from riskplan.scenarios.base import rollout
    from riskplan.tissue_planning.rrt import RRTOptions, rrt_plans, sampling_bounds

    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    sim = make_scenario(str(path))
    assert np.isclose(sim.config.width, 0.08, **TOL_EXACT)
    assert np.isclose(sim.config.v_max, 0.04, **TOL_EXACT)
    b = sampling_bounds(sim, RRTOptions())
    assert np.isclose(b[0, 0], 2 * 0.004, **TOL_EXACT)
    # the old fixed constant: no speed left to sample
    fixed = NeedleScenario(
        NeedleConfig(**{**_kw(sim.config), "actuation_std": NEEDLE_ACTUATION_STD})
    )
    with pytest.raises(InvalidInputError, match="leave no controls"):
        sampling_bounds(fixed, RRTOptions())
    params = SimParams(n_elements=60)
    plans, _ = rrt_plans(
        sim,
        2,
        seed=3,
        params=params,
        options=RRTOptions(plans_per_tree=2, max_iterations=1200),
        backend="serial",
    )
    assert len(plans) == 2
    for p in plans:
        states = rollout(sim, sim.initial_state(params), p.controls, params)
        assert sim.in_goal(states[-1])
        assert not any(sim.in_collision(s) for s in states)


def _kw(cfg):
    return {f.name: getattr(cfg, f.name) for f in fields(cfg)}


def _write(tmp_path, text):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("width = 80.0", "widht = 80.0", r"unknown key 'tissue.widht' \(did you mean 'width'\?\)"),
        ("[goal]", "[goals]", r"unknown key 'goals' \(did you mean 'goal'\?\)"),
        ("radius = 6.0", "", r"goal.radius: missing field"),
        ("center = [60.0, 36.0]", "center = [79.0, 36.0]", r"goal: lies outside the tissue"),
        ("start = [4.0, 30.0, 0.0]", "start = [-4.0, 30.0, 0.0]", r"robot.start: lies outside"),
        ("hi = [40.0, 25.0]", "hi = [40.0, 65.0]", r"obstacles\[0\]: lies outside the tissue"),
        ('length = "mm"', 'length = "inch"', r"units.length: expected one of"),
        ("v_max = 40.0", 'v_max = "fast"', r"controls.v_max: expected a number"),
        ("phi_max = 60.0", "phi_max = 95.0", r"controls.phi_max: must be below 90"),
        ('kind = "needle"', 'kind = "car"', r"kind: expected one of"),
        ("poissons_ratio = 0.4", "poissons_ratio = 0.5", r"material.poissons_ratio: must lie"),
    ],
)
def test_bad_needle_files_rejected_naming_file_and_field(tmp_path, old, new, match):
    assert old in SMALL
    p = _write(tmp_path, SMALL.replace(old, new, 1))
    with pytest.raises(InvalidInputError, match=match) as exc:
        make_scenario(str(p))
    assert str(p) in str(exc.value)


def test_bad_manipulation_files_rejected(tmp_path):
    text = shipped_path("manipulation").read_text()
    cases = [
        ("[0.5, 1.0]]", "[0.5, 0.9]]", r"manipulators.points\[2\]: must lie on the tissue outline"),
        ("target = [0.45, 0.5]", "target = [0.9, 0.1]", r"tissue.target: lies outside"),
        ("center = [-0.25, 0.2]", "center = [0.05, 0.2]", r"obstacles\[0\]: overlaps"),
        ("fixed_edge = 1", "fixed_edge = 5", r"tissue.fixed_edge: expected an edge index"),
        ("df_max = 0.375", "df_maxx = 0.375", r"did you mean 'df_max'"),
    ]
    for old, new, match in cases:
        assert old in text
        p = _write(tmp_path, text.replace(old, new, 1))
        with pytest.raises(InvalidInputError, match=match):
            make_scenario(str(p))


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(InvalidInputError, match="no such file"):
        make_scenario(str(tmp_path / "nope.toml"))
    with pytest.raises(InvalidInputError, match="not a valid TOML"):
        make_scenario(str(_write(tmp_path, "kind = ")))


def test_manipulation_file_material_and_noise_reach_the_scenario(tmp_path):
    text = shipped_path("manipulation").read_text()
    text = text.replace("youngs_modulus = 50.0", "youngs_modulus = 80.0").replace(
        "n_boundary = 12", "n_boundary = 12\nactuation_std = 0.01"
    )
    sim = make_scenario(str(_write(tmp_path, text)), "actuation")
    assert isinstance(sim, ManipulationScenario)
    assert sim.nominal_params.youngs_modulus == 80.0
    assert np.allclose(np.diag(sim.distribution.variance), 1e-4, **TOL_EXACT)
    assert geo.polygon_area(sim.config.outline) > 0


def test_cli_simulate_and_plan_take_a_scenario_file(tmp_path):
    import json

    from typer.testing import CliRunner

    from riskplan.cli import app

    runner = CliRunner()
    scene = _write(tmp_path, SMALL)
    out = tmp_path / "sim"
    r = runner.invoke(
        app,
        [
            "tissue",
            "simulate",
            "--scenario",
            str(scene),
            "--out",
            str(out),
            "--steps",
            "4",
            "--max-frames",
            "2",
        ],
    )
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == 4 and (out / "needle.gif").is_file()
    # a bad file fails before anything is written
    bad = tmp_path / "typo.toml"
    bad.write_text(SMALL.replace("r_min", "rmin"))
    for cmd in (["tissue", "simulate"], ["plan", "tissue", "--plans", "2"]):
        out = tmp_path / f"out_{cmd[0]}"
        r = runner.invoke(app, [*cmd, "--scenario", str(bad), "--out", str(out)])
        assert isinstance(r.exception, InvalidInputError)
        msg = str(r.exception)
        assert "unknown key 'robot.rmin' (did you mean 'r_min'?)" in msg and str(bad) in msg
        assert not out.exists()


def test_material_cases_centre_on_the_files_material(tmp_path):
    """A file's nominal E = 80: the material cases draw around 80 with the paper's relative
    spread (variance 75 (80/50)^2), not around the paper's 50; the paper's scene keeps
    N(50, 75) exactly."""
    paper = make_scenario("needle", "material-high").distribution
    assert (paper.youngs_mean, paper.youngs_var, paper.poisson_mean) == (50.0, 75.0, 0.4)
    text = (
        shipped_path("needle").read_text().replace("youngs_modulus = 50.0", "youngs_modulus = 80.0")
    )
    dist = make_scenario(str(_write(tmp_path, text)), "material-high").distribution
    assert dist.youngs_mean == 80.0 and dist.planning_params.youngs_modulus == 80.0
    assert np.isclose(dist.youngs_var, 75.0 * (80.0 / 50.0) ** 2, **TOL_EXACT)
    draws = np.array([p.youngs_modulus for p in dist.sample_many(400, seed=1)])
    # sample mean within 4 standard errors of 80
    assert abs(draws.mean() - 80.0) < 4.0 * math.sqrt(dist.youngs_var / len(draws))


def _obj(path, verts, faces):
    lines = [f"v {x} {y} {z}" for x, y, z in verts] + [
        f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces
    ]
    path.write_text("\n".join(lines) + "\n")


def test_manipulation_tissue_from_a_mesh_file(tmp_path):
    """A planar OBJ of the paper's object (fan triangles listed clockwise, with an interior
    vertex): its boundary loop is the paper's outline, counter-clockwise, and the fixed
    edge given by its two vertices is the paper's."""
    pytest.importorskip("trimesh")
    outline = [[0.0, 0.0], [0.7, 0.0], [1.0, 0.3], [1.0, 1.0], [0.0, 1.0]]
    verts = [(x, y, 0.2) for x, y in outline] + [(0.5, 0.5, 0.2)]
    faces = [(5, (i + 1) % 5, i) for i in range(5)]  # clockwise
    _obj(tmp_path / "object.obj", verts, faces)
    text = shipped_path("manipulation").read_text()
    text = text.replace(
        "outline = [[0.0, 0.0], [0.7, 0.0], [1.0, 0.3], [1.0, 1.0], [0.0, 1.0]]",
        'mesh = "object.obj"',
    ).replace("fixed_edge = 1", "fixed = [[1.0, 0.3], [0.7, 0.0]]")
    kind, cfg = read_scenario_config(_write(tmp_path, text))
    paper = ManipulationConfig()
    assert kind == "manipulation" and len(cfg.outline) == 5
    assert np.isclose(geo.polygon_area(cfg.outline), geo.polygon_area(paper.outline), **TOL_EXACT)
    assert {tuple(p) for p in cfg.outline.tolist()} == {tuple(p) for p in outline}
    seg = {tuple(p) for p in cfg.fixed_segment.tolist()}
    assert seg == {tuple(p) for p in paper.fixed_segment.tolist()}
    # not planar: rejected, naming the field
    _obj(tmp_path / "object.obj", [*verts[:5], (0.5, 0.5, 0.4)], faces)
    with pytest.raises(InvalidInputError, match=r"tissue.mesh: object.obj is not planar"):
        read_scenario_config(tmp_path / "bad.toml")
    # a fixed 'edge' that is not one
    bad = text.replace("fixed = [[1.0, 0.3], [0.7, 0.0]]", "fixed = [[1.0, 0.3], [0.0, 0.0]]")
    _obj(tmp_path / "object.obj", verts, faces)
    with pytest.raises(InvalidInputError, match=r"tissue.fixed: the two vertices must be"):
        read_scenario_config(_write(tmp_path, bad))
