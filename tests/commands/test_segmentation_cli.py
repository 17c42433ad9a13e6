"""`riskplan env from-segmentation`: a label map in millimetres to a mesh in metres with its sidecar."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.collision import Environment
from tests.conftest import TOL

sitk = pytest.importorskip("SimpleITK")
pytest.importorskip("skimage")
pytest.importorskip("pymeshlab")

runner = CliRunner()


@pytest.fixture
def labels_mm(tmp_path):
    """A 24 mm sphere (label 2) in a 1 mm volume stored in millimetres, as CT segmentations are."""
    k, j, i = np.meshgrid(*[np.arange(32)] * 3, indexing="ij")
    labels = np.where((i - 15.5) ** 2 + (j - 15.5) ** 2 + (k - 15.5) ** 2 <= 12.0**2, 2, 0)
    img = sitk.GetImageFromArray(labels.astype(np.uint8))
    img.SetOrigin((-100.0, 20.0, 5.0))
    path = tmp_path / "organ.nrrd"
    sitk.WriteImage(img, str(path))
    return path


def test_from_segmentation_writes_mesh_and_sidecar(labels_mm, tmp_path):
    out = tmp_path / "organ.stl"
    res = runner.invoke(
        app,
        ["env", "from-segmentation", str(labels_mm), "--label", "2", "--scale", "0.001",
         "--faces", "800", "--out", str(out)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    env = Environment.load(out)
    meta = json.loads((tmp_path / "organ.stl.json").read_text())
    assert env.n_faces == meta["triangles"] <= 800
    assert meta["label"] == 2 and meta["frame"] == "world" and meta["base_pose"] is None
    assert meta["scale_to_metres"] == 0.001
    # the sphere's centre in metres: origin + 15.5 voxels of 1 mm
    centre = env.vertices.mean(axis=0)
    assert np.linalg.norm(centre - np.array([-84.5, 35.5, 20.5]) * 1e-3) <= 1e-3  # one voxel
    # without a base pose the mesh is not read as if the volume were the robot's frame
    res = runner.invoke(
        app, ["collision", "probability", "--env", str(out), "--arc", "8,0", "--samples", "100"]
    )
    assert res.exit_code != 0 and "--base-pose" in str(res.exception)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--label", "5"], "--label 5: no voxel has this label; labels present: 2"),
        (["--label", "2"], "look like millimetres where metres are expected"),
    ],
)
def test_from_segmentation_bad_input_writes_nothing(labels_mm, tmp_path, args, message):
    out = tmp_path / "bad.stl"
    res = runner.invoke(app, ["env", "from-segmentation", str(labels_mm), *args, "--out", str(out)])
    assert res.exit_code != 0
    assert message in str(res.exception)
    assert str(labels_mm) in str(res.exception)
    assert not out.exists() and not (tmp_path / "bad.stl.json").exists()


def test_from_segmentation_with_a_ros_order_base_pose(labels_mm, tmp_path):
    """--base-pose in ROS quaternion order: the sidecar stores the pose, and the mesh loads in
    the robot base frame as x_base = R^T (x - p)."""
    from scipy.spatial.transform import Rotation

    from riskplan.collision.mesh_files import load_environment

    out = tmp_path / "organ.stl"
    q_xyzw = Rotation.from_euler("z", 90, degrees=True).as_quat()  # (x, y, z, w)
    pose = "xyzw:-0.08,0.03,0.02," + ",".join(repr(float(v)) for v in q_xyzw)
    res = runner.invoke(
        app,
        ["env", "from-segmentation", str(labels_mm), "--label", "2", "--scale", "0.001",
         "--faces", "600", "--base-pose", pose, "--out", str(out)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / "organ.stl.json").read_text())
    assert meta["frame"] == "world"
    np.testing.assert_allclose(
        meta["base_rotation"], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], **TOL["orthonormality"]
    )
    world = Environment.load(out)
    base = load_environment(out)
    R = np.array(meta["base_rotation"])
    np.testing.assert_allclose(
        base.vertices, (world.vertices - [-0.08, 0.03, 0.02]) @ R, **TOL["float64_exact"]
    )
