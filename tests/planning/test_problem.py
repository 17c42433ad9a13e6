"""Problem files: the lab's task file, start/goal in tensions or displacements, the voxel
environment's frames (quaternion order checked on the lab's data), and bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.planning.problem import ProblemFileError, load_problem
from riskplan.planning.problem_voxels import VoxelEnvironment
from riskplan.robots.params import quaternion_to_matrix
from tests.conftest import TOL

LAB = Path(__file__).resolve().parents[1] / "data" / "kuntz-lab"
TASK = LAB / "task-0001.toml"
STL = "collapse-segmentation-reoriented-with-hole-3k.stl"
VOXELS = "collapse-segmentation-moved-with-hole.msgpack"


@pytest.fixture(scope="module")
def problem():
    return load_problem(TASK)


def _copy_task(tmp_path, old=None, new=None, *, with_files=True) -> Path:
    text = TASK.read_text()
    if old is not None:
        assert old in text
        text = text.replace(old, new, 1)
    out = tmp_path / "task.toml"
    out.write_text(text)
    if with_files:
        for f in (STL, VOXELS):
            shutil.copy(LAB / f, tmp_path / f)
    return out


def test_task_file(problem):
    np.testing.assert_array_equal(problem.start, [0, 0, 0, 0, 0.119])
    np.testing.assert_array_equal(problem.goal, [1.0712, 0.459471, 2.81962, -0.589326, 0.0267231])
    assert problem.min_tension_change == 0.005 and problem.n_config == 5
    assert problem.meshes == ((LAB / STL).resolve(),)
    v = problem.voxel_environment
    assert v.filename == (LAB / VOXELS).resolve() and v.scaling == 0.001
    assert v.translation == (108.9, 165.3, 204.2) and v.rotation_quat == (
        0.665,
        -0.052,
        0.744,
        0.035,
    )
    # zero tensions hold zero displacement at any retraction
    np.testing.assert_allclose(problem.start_displacements, 0.0, **TOL["float64_abs"])
    shape = problem.shape(problem.start)
    np.testing.assert_allclose(shape.tip, [0, 0, 0.12 - 0.119], **TOL["float64_abs"])


def test_start_goal_in_displacements_give_the_same_configuration(problem, tmp_path):
    """Tensions -> displacements (the file's goal) -> tensions (a file that gives them)."""
    d = problem.goal_displacements
    path = _copy_task(
        tmp_path,
        "goal = [ 1.0712, 0.459471, 2.81962,]",
        "goal_displacements = [" + ", ".join(repr(float(x)) for x in d) + "]",
    )
    other = load_problem(path)
    np.testing.assert_allclose(other.goal, problem.goal, **TOL["tension_solve"])
    np.testing.assert_allclose(
        other.shape(other.goal).positions,
        problem.shape(problem.goal).positions,
        **TOL["solver"],
    )


def test_voxel_quaternion_is_scalar_first_and_maps_robot_to_voxels(problem):
    """A voxel landmark lands on the STL (already in the robot frame) only with the lab's
    convention: ``(w, x, y, z)``, ``x_voxel = R x_robot``. Measured on 2,000 of the occupied
    cells: 99th percentile of the distance to the STL 5.5 mm with it; 41 mm reading the
    quaternion as (x, y, z, w); 92 mm with R applied the other way round."""
    import trimesh

    mesh = problem.load_meshes()
    grid = problem.voxel_environment.load()
    centers = grid.centers()
    sub = centers[np.random.default_rng(0).choice(len(centers), 2000, replace=False)]

    def p99(points):
        return np.percentile(trimesh.proximity.closest_point(mesh, points)[1], 99)

    v = problem.voxel_environment
    w, x, y, z = v.rotation_quat
    assert p99(v.voxel_to_robot(sub)) < 0.006
    assert p99(sub @ quaternion_to_matrix((z, w, x, y))) > 0.03  # file read as (x, y, z, w)
    assert p99(v.robot_to_voxel(sub)) > 0.03  # R^T and R swapped
    np.testing.assert_allclose(v.robot_to_voxel(v.voxel_to_robot(sub)), sub, **TOL["float64_exact"])


def test_voxel_scaling_and_translation_map_the_segmentation_into_the_voxel_grid(problem):
    """``x_voxel = scaling (x_image + translation)``: the source segmentation's origin (its NRRD
    header, ``collapse-segmentation.nrrd``: (-162.2041015625, -288.2041015625, -331.70001220703125)
    mm) lands on the first cell centre of the voxel file, within a hundredth of a cell."""
    v = problem.voxel_environment
    grid = v.load()
    origin_mm = np.array([-162.2041015625, -288.20410156250011, -331.70001220703125])
    first_cell = grid.limits[:, 0] + 0.5 * grid.spacing
    assert np.all(np.abs(v.image_to_voxel(origin_mm) - first_cell) < 0.01 * grid.spacing)
    assert grid.dimension == 512


def test_nested_layout_problem_at_top_level(tmp_path):
    from tests.robots.test_lab_format import NESTED

    path = tmp_path / "effusion.toml"
    text = NESTED.replace(
        "[robot]", "[[environment.spheres]]\ncenter = [0.0, 0.01, 0.05]\nradius = 0.004\n[robot]"
    )
    text = text.replace(
        "goal = [1.0, 0.5, 2.0]",
        "goal = [1.0, 0.5, 2.0]\nstart_rotation = 0.0\ngoal_rotation = 0.5\n"
        "start_retraction = 0.0\ngoal_retraction = 0.05",
    )
    path.write_text(text)
    pr = load_problem(path)
    np.testing.assert_array_equal(pr.goal, [1.0, 0.5, 2.0, 0.5, 0.05])
    assert pr.spheres[0].radius == 0.004 and pr.min_tension_change == 0.005


@pytest.mark.parametrize(
    ("old", "new", "field", "words"),
    [
        ("goal = [ 1.0712,", "goal = [ 4.2,", "problem.goal[0]", "tension limits"),
        ("start = [ 0, 0, 0,]", "start = [ 0, -0.1, 0,]", "problem.start[1]", "tension limits"),
        (
            "goal_retraction = 0.0267231",
            "goal_retraction = 0.2",
            "problem.goal_retraction",
            "outside",
        ),
        ("goal_rotation = -0.589326\n", "", "problem.goal_rotation", "required"),
        (
            "min_tension_change",
            "min_tension_chang",
            "problem.min_tension_chang",
            "min_tension_change",
        ),
        ("[[environment.meshes]]", "[[environment.mesh]]", "environment.mesh", "meshes"),
        (STL, "missing.stl", "environment.meshes[0].filename", "no such file"),
        ("scaling = 0.001", "scalling = 0.001", "voxel_environment.scalling", "scaling"),
        ("goal = [ 1.0712, 0.459471, 2.81962,]", "goal = [1.0, 0.5]", "problem.goal", "3 entries"),
    ],
)
def test_bad_problem_files_name_file_and_field(tmp_path, old, new, field, words):
    path = _copy_task(tmp_path, old, new)
    with pytest.raises(ProblemFileError) as err:
        load_problem(path)
    msg = str(err.value)
    assert str(path) in msg and field in msg and words in msg, msg
    assert err.value.key == field
    assert isinstance(err.value, InvalidInputError)


def test_displacement_goal_above_max_tension_is_refused(tmp_path):
    path = _copy_task(
        tmp_path, "goal = [ 1.0712, 0.459471, 2.81962,]", "goal_displacements = [0.04, 0.0, 0.0]"
    )
    with pytest.raises(ProblemFileError, match=r"problem.goal_displacements\[0\].*max_tension"):
        load_problem(path)


def test_millimetre_mesh_is_refused(tmp_path):
    import trimesh

    path = _copy_task(tmp_path)
    mesh = trimesh.load_mesh(tmp_path / STL)
    mesh.apply_scale(1000.0)
    mesh.export(tmp_path / STL)
    pr = load_problem(path)  # the file is fine; the units show when the mesh is read
    with pytest.raises(ProblemFileError, match="millimetres"):
        pr.load_meshes()
    assert pr.load_meshes(check_units=False) is not None


def test_voxel_environment_defaults_are_identity():
    v = VoxelEnvironment(None)
    pts = np.array([[0.1, -0.2, 0.3]])
    np.testing.assert_array_equal(v.voxel_to_robot(pts), pts)
    with pytest.raises(InvalidInputError, match="no filename"):
        v.load()


def test_planner_facing_limits_and_interpolation(problem):
    lim = problem.configuration_limits
    np.testing.assert_array_equal(lim[:3], [[0, 3.5]] * 3)
    assert lim[3, 0] == -np.pi and lim[4, 1] < 0.12
    a = np.array([0.0, 1.0, 2.0, 3.0, 0.1])
    b = np.array([2.0, 1.0, 0.0, -3.0, 0.0])
    mid = problem.interpolate(a, b, 0.5)
    np.testing.assert_allclose(mid[[0, 1, 2, 4]], [1.0, 1.0, 1.0, 0.05], **TOL["float64_abs"])
    # 3 rad to -3 rad is 0.28 rad the short way, through pi
    np.testing.assert_allclose(abs(mid[3]), np.pi, **TOL["float64_abs"])
    ends = problem.interpolate(a, b, np.array([0.0, 1.0]))
    np.testing.assert_allclose(ends, np.stack([a, b]), **TOL["float64_abs"])


def test_riskplans_own_format_carries_a_problem(tmp_path):
    """A riskplan robot file with [problem] and [environment]: displacements for the start,
    tensions for the goal; the paper robot has no base motion, so none is asked for."""
    from importlib import resources

    from riskplan.robots import load_robot

    paper = resources.files("riskplan").joinpath("data", "paper_robot.toml").read_text()
    path = tmp_path / "paper_task.toml"
    path.write_text(
        paper
        + "\n[problem]\nstart_displacements = [0.0, 0.0, 0.0, 0.0]\ngoal = [2.0, 0.0, 1.0, 0.0]\n"
        + "[[environment.spheres]]\ncenter = [0.05, 0.0, 0.15]\nradius = 0.01\n"
    )
    pr = load_problem(path)
    robot = load_robot("paper")
    np.testing.assert_array_equal(pr.goal, [2.0, 0.0, 1.0, 0.0])
    np.testing.assert_allclose(
        pr.goal_displacements,
        robot.displacements_for_tensions([2.0, 0.0, 1.0, 0.0]),
        **TOL["float64_exact"],
    )
    np.testing.assert_allclose(pr.start, 0.0, **TOL["float64_abs"])
    assert pr.spheres[0].center == (0.05, 0.0, 0.15) and pr.voxel_environment is None
    np.testing.assert_allclose(
        pr.shape(pr.goal).tip, robot.solve_tensions(pr.goal).tip, **TOL["float64_exact"]
    )
