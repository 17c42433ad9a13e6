"""The Kuntz lab's segmentation against the lab's own surface mesh (real data).

``tests/data/kuntz-lab/collapse-segmentation.nrrd`` (label 2, 512 x 512 x 63 voxels of
0.59 x 0.59 x 5 mm, LPS millimetres) is the volume the lab's
``collapse-segmentation-reoriented-with-hole-3k.stl`` (3,361 triangles, metres, robot frame) came
from; both unchanged from Kuntz-Lab/Tendon_Robot_Learning (``resources/collapse-segmentation/``,
BSD-3 licence beside them). The STL is the reference: our mesh of the label, moved into the
robot frame by the lab's voxel-environment transform, must have its volume, centroid and surface.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from riskplan.collision.segmentation import segmentation_mesh
from riskplan.robots.params import quaternion_to_matrix
from tests.conftest import TOL

pytest.importorskip("SimpleITK")
pytest.importorskip("skimage")
pytest.importorskip("pymeshlab")

LAB = Path(__file__).resolve().parents[1] / "data" / "kuntz-lab"
# [voxel_environment] of the lab's task files: scaling, translation (mm), rotation quaternion
# read as (w, x, y, z); the voxel frame maps to the robot frame by x_robot = R^T (x + t) * scaling
SCALING = 0.001
TRANSLATION = np.array([108.9, 165.3, 204.2])
ROTATION_WXYZ = np.array([0.665, -0.052, 0.744, 0.035])
IN_PLANE_VOXEL = 0.591796875e-3  # m


@pytest.fixture(scope="module")
def ours_and_lab():
    V, F, info = segmentation_mesh(
        LAB / "collapse-segmentation.nrrd", 2, faces=3361, scale=SCALING, robot_length=0.12
    )
    R = quaternion_to_matrix(ROTATION_WXYZ)
    X = (V + TRANSLATION * SCALING) @ R  # rows: R^T (x + t s)
    lab = trimesh.load(LAB / "collapse-segmentation-reoriented-with-hole-3k.stl")
    return trimesh.Trimesh(X, F, process=False), lab, info


def test_lab_segmentation_gives_the_labs_surface(ours_and_lab):
    ours, lab, info = ours_and_lab
    assert info["triangles"] <= 3361 and ours.is_watertight
    assert ours.volume == pytest.approx(lab.volume, rel=TOL["segmentation_volume"]["rtol"])
    assert np.linalg.norm(ours.center_mass - lab.center_mass) <= IN_PLANE_VOXEL
    # every part of the lab's surface is on ours: 95 % within two in-plane voxels (slices are
    # 5 mm apart, so the staircase between them is the larger error)
    pts = lab.sample(3000, seed=0)
    _, d, _ = trimesh.proximity.closest_point(ours, pts)
    assert np.percentile(d, 95) <= 2 * IN_PLANE_VOXEL
    assert d.max() <= 5e-3  # one slice spacing (m)
