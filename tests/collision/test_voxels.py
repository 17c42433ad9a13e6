"""Voxel obstacles (riskplan.collision.voxels): the exact boundary surface of the occupied
cells against the direct cell test, the eq.-9 bound of mixtures against voxels against Monte
Carlo on the cells themselves, and a problem's voxels and points in the planner's scene."""

from __future__ import annotations

import json

import numpy as np
import pytest

from riskplan.collision import probability_of_collision
from riskplan.collision.gaussian import precision_cholesky_from_covariance
from riskplan.collision.geometry import signed_volume
from riskplan.collision.montecarlo import binomial_interval
from riskplan.collision.voxels import voxel_boundary_mesh, voxel_environment, voxels_contain
from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import NumpyMixture
from tests.conftest import TOL

ORIGIN = np.array([0.01, -0.02, 0.05])
SPACING = np.array([0.002, 0.002, 0.0025])


def _blob(rng):
    """A random blob of cells with diagonal-only contacts (non-manifold edges) and a cavity."""
    occ = np.argwhere(rng.uniform(size=(7, 6, 5)) < 0.45)
    occ = np.vstack([occ, [[10, 10, 10], [11, 11, 10]]])  # two cells touching along an edge
    return occ


def test_surface_is_the_union_of_the_cells(rng):
    occ = _blob(rng)
    V, F = voxel_boundary_mesh(occ, ORIGIN, SPACING)
    # enclosed volume = number of cells x cell volume; outward orientation
    np.testing.assert_allclose(
        signed_volume(V, F), len(np.unique(occ, axis=0)) * np.prod(SPACING), **TOL["float64_exact"]
    )
    env = voxel_environment(occ, ORIGIN, SPACING)
    lo, hi = ORIGIN - SPACING, ORIGIN + 13 * SPACING
    # points off the cell faces (the half-open direct test and the winding number differ only
    # on faces, a set of measure zero)
    P = rng.uniform(lo, hi, size=(40_000, 3))
    np.testing.assert_array_equal(env.contains(P), voxels_contain(P, occ, ORIGIN, SPACING))
    with pytest.raises(InvalidInputError, match="occupied"):
        voxel_boundary_mesh(np.zeros((0, 3), int), ORIGIN, SPACING)
    with pytest.raises(InvalidInputError, match="reflection"):
        voxel_environment(occ, ORIGIN, SPACING, transform=lambda v: v * [1, 1, -1])


def test_bound_against_voxels_is_above_monte_carlo_on_the_cells(rng):
    """Eq. 9 against the voxel surface bounds the probability that a mixture point lies in
    a cell, measured by sampling the mixture and testing the cells directly (20,000 draws per
    mixture, 95 % Wilson intervals): the bound is at or above each interval's lower end, and
    below 1 where the mixture is a few standard deviations from the cells."""
    occ = _blob(rng)
    B, K, n = 6, 3, 20_000
    centre = ORIGIN + 3.5 * SPACING
    means = centre + rng.uniform(-0.02, 0.02, size=(B, K, 3))
    std = rng.uniform(0.002, 0.006, size=(B, K, 3))
    cov = np.einsum("bki,ij->bkij", std**2, np.eye(3))
    w = rng.dirichlet(np.ones(K), size=B)
    env = voxel_environment(occ, ORIGIN, SPACING)
    inside = voxels_contain(means, occ, ORIGIN, SPACING)
    means[inside] += 0.03  # means in free space (a mean inside a cell is a bound of 1)
    gm = NumpyMixture(w, means, precision_cholesky_from_covariance(cov))
    bound = probability_of_collision(gm, env, "bound")
    hits = np.zeros(B, dtype=np.int64)
    for b in range(B):
        comp = rng.choice(K, size=n, p=w[b])
        x = means[b, comp] + std[b, comp] * rng.standard_normal((n, 3))
        hits[b] = voxels_contain(x, occ, ORIGIN, SPACING).sum()
    low, _ = binomial_interval(hits, n, 0.95)
    assert np.all(bound >= low), (bound, hits / n)
    assert np.any(hits > 0) and np.any(bound < 1.0)


def _voxel_file(path, occ, N, limits):
    """The lab's VoxelOctree JSON form of occupied cells (4x4x4 blocks, bit 16x + 4y + z)."""
    blocks: dict = {}
    for x, y, z in occ.tolist():
        b = (int(x) // 4, int(y) // 4, int(z) // 4)
        blocks[b] = blocks.get(b, 0) | (1 << (16 * (x % 4) + 4 * (y % 4) + (z % 4)))
    data = [[*b, bits] for b, bits in blocks.items()]
    path.write_text(
        json.dumps(
            {
                "VoxelOctree": {
                    "dimension": N,
                    "xlimits": limits[0],
                    "ylimits": limits[1],
                    "zlimits": limits[2],
                    "data": data,
                }
            }
        )
    )


def test_problem_voxels_and_points_are_in_the_planners_scene(tmp_path):
    """A problem with only a voxel environment and points: the scene holds the cells (moved into
    the robot frame by the file's quaternion) and a sphere of the robot's radius about each
    point; 'off' leaves nothing to plan against and is refused; the lab's task (an STL and
    voxels of the same anatomy) uses the STL alone under 'auto'."""
    from pathlib import Path

    from riskplan.planning.problem import load_problem
    from riskplan.planning.problem_scene import problem_environment

    lab = Path(__file__).parents[1] / "data" / "kuntz-lab" / "task-0001.toml"
    text = lab.read_text()
    robot = text[: text.index("[problem]")] + text[text.index("[tendon_robot]") :]
    occ = np.array([[x, y, z] for x in range(4, 8) for y in range(0, 8) for z in range(8, 12)])
    _voxel_file(tmp_path / "v.json", occ, 16, [[0.02, 0.06], [-0.02, 0.02], [0.0, 0.04]])
    (tmp_path / "p.toml").write_text(
        robot
        + """
[problem]
start = [0, 0, 0]
start_rotation = 0
start_retraction = 0
goal = [0.5, 0, 0]
goal_rotation = 0
goal_retraction = 0

[environment]
[[environment.points]]
point = [-0.03, 0.0, 0.08]

[voxel_environment]
filename = "v.json"
rotation_quat = [0.7071067811865476, 0.0, 0.0, 0.7071067811865476]
"""
    )
    prob = load_problem(tmp_path / "p.toml")
    env = problem_environment(prob)
    assert env.n_obstacles == 2
    grid = prob.voxel_environment.load()
    centres = grid.centers()
    # cell centres are inside once moved into the robot frame (R^T, a quarter turn about z)
    assert np.all(env.contains(prob.voxel_environment.voxel_to_robot(centres)))
    assert not np.any(env.contains(centres))
    r = prob.robot.params.collision_radius
    assert r == 0.003
    p = np.array([-0.03, 0.0, 0.08])
    assert env.contains(p + [0.9 * r, 0, 0]) and not env.contains(p + [1.1 * r, 0, 0])
    # voxels off: the point alone is planned against
    assert problem_environment(prob, voxels="off").n_obstacles == 1
    with pytest.raises(InvalidInputError, match="voxels"):
        problem_environment(prob, voxels="sometimes")
    lab_env = problem_environment(load_problem(lab))
    assert "voxels" not in lab_env.names
