"""Data-set protocols for robots other than the paper's: presets adapt to the tendon count,
base rotation/retraction and tension limits; arrivals above max_tension are counted and named."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from riskplan.datasets import generate_dataset, load_dataset
from riskplan.datasets.protocol import (
    PRESETS,
    Protocol,
    exposure_upper,
    grid_levels_for,
    protocol_for_robot,
    protocol_limits,
    scale_by_exposure,
    target_configurations,
)
from riskplan.datasets.summary import over_max_tension, summarize
from riskplan.errors import InvalidInputError
from riskplan.robots import load_robot
from riskplan.robots.description import parse_robot_toml
from riskplan.robots.robot import TendonRobot
from tests.conftest import TOL

TASK = Path(__file__).resolve().parents[1] / "data" / "kuntz-lab" / "task-0001.toml"

THREE = """
name = "my3tendon"
[backbone]
length = 0.15
outer_radius = 0.0025
youngs_modulus = 6e7
[[tendons]]
theta = [0.0]
radius = [0.006]
stiffness = 500.0
displacement_limits = [-0.005, 0.03]
max_tension = 6.0
[[tendons]]
theta = [2.0944]
radius = [0.006]
stiffness = 500.0
displacement_limits = [-0.005, 0.03]
max_tension = 6.0
[[tendons]]
theta = [-2.0944]
radius = [0.006]
stiffness = 500.0
displacement_limits = [-0.005, 0.03]
max_tension = 6.0
"""


@pytest.fixture(scope="module")
def three():
    return TendonRobot(parse_robot_toml(THREE), toml_text=THREE)


@pytest.fixture(scope="module")
def lab():
    return load_robot(TASK)


def test_grid_levels_keep_at_least_the_presets_grid():
    assert grid_levels_for(8, 4) == 8 and grid_levels_for(3, 4) == 3
    assert grid_levels_for(8, 3) == 16 and grid_levels_for(3, 3) == 5 and grid_levels_for(2, 3) == 3
    assert grid_levels_for(8, 5) == 6 and grid_levels_for(3, 5) == 3 and grid_levels_for(2, 5) == 2
    for levels in (2, 3, 8):
        for d in (1, 2, 3, 5, 6):
            L = grid_levels_for(levels, d)
            assert L**d >= levels**4 and (L == 2 or (L - 1) ** d < levels**4)


@pytest.mark.parametrize("name", ["paper", "small", "tiny"])
def test_paper_robot_presets_are_unchanged(name):
    robot = load_robot("paper")
    p = protocol_for_robot(name, robot)
    assert p is PRESETS[name]
    assert "limits" not in json.loads(p.to_json()) and "scale_by_exposure" not in p.to_json()


@pytest.mark.parametrize("name", ["paper", "small", "tiny"])
def test_three_tendon_presets_fit_with_the_same_budget(three, name):
    """Before: 'n_train + n_test = 75 exceeds the 27 points of a 3-level grid'."""
    base = PRESETS[name]
    if name != "tiny":  # tiny's 8 targets fit 2^3 points
        with pytest.raises(InvalidInputError, match="grid_levels >="):
            target_configurations(base, three.displacement_limits, "train")
    p = protocol_for_robot(name, three)
    assert (p.n_train, p.n_test, p.n_starts, p.n_points) == (
        base.n_train,
        base.n_test,
        base.n_starts,
        base.n_points,
    )
    assert p.grid_levels == grid_levels_for(base.grid_levels, 3)
    lim = protocol_limits(p, three)
    tr = target_configurations(p, lim, "train")
    te = target_configurations(p, lim, "test")
    assert tr.shape == (base.n_train, 3) and te.shape == (base.n_test, 3)


def test_limits_clip_to_the_tension_limits(lab):
    """A tendon alone at its upper grid value carries exactly max_tension (fully exposed)."""
    p = protocol_for_robot("small", lab)
    lim = protocol_limits(p, lab)
    assert lim.shape == (5, 2) and p.scale_by_exposure
    file_lim = lab.configuration_limits
    np.testing.assert_array_equal(lim[:3, 0], file_lim[:3, 0])
    assert np.all(lim[:3, 1] < file_lim[:3, 1])  # 26.7 mm at 3.5 N, the file allows 48 mm
    for i in range(3):
        d = np.zeros(3)
        d[i] = lim[i, 1]
        tau = lab.tensions_for_displacements(d)
        np.testing.assert_allclose(tau[i], 3.5, **TOL["tension_solve"])
    # the rotation's full turn is periodic: the grid stops one step short of +pi
    L = p.grid_levels
    np.testing.assert_allclose(
        lim[3], [-np.pi, -np.pi + 2 * np.pi * (L - 1) / L], **TOL["float64_abs"]
    )
    np.testing.assert_array_equal(lim[4], file_lim[4])


def test_scale_by_exposure_maps_onto_the_box_at_each_retraction(lab):
    p = protocol_for_robot("small", lab)
    lim = protocol_limits(p, lab)
    q = np.array(
        [[lim[0, 1], lim[1, 0], 0.5 * (lim[2, 0] + lim[2, 1]), 0.0, r] for r in (0.0, 0.06, 0.119)]
    )
    out = scale_by_exposure(q, lab, lim)
    for k, r in enumerate((0.0, 0.06, 0.119)):
        h = exposure_upper(lab, r, lim)
        np.testing.assert_allclose(out[k, 0], h[0], **TOL["float64_abs"])  # top stays the top
        np.testing.assert_allclose(out[k, 1], lim[1, 0], **TOL["float64_abs"])  # bottom stays
        np.testing.assert_allclose(out[k, 2], 0.5 * (lim[2, 0] + h[2]), **TOL["float64_abs"])
        tau = lab.tensions_for_displacements(np.array([h[0], lim[1, 0], lim[2, 0]]), retraction=r)
        np.testing.assert_allclose(tau[0], 3.5, **TOL["tension_solve"])
    np.testing.assert_array_equal(out[:, 3:], q[:, 3:])


def test_custom_protocol_is_taken_as_given(three):
    custom = Protocol(name="custom", grid_levels=4, n_train=20, n_test=5, n_starts=2)
    assert protocol_for_robot(custom, three) is custom
    assert protocol_for_robot(custom.to_json(), three) == custom
    bad = Protocol(limits=((0.0, 0.01),) * 2)
    with pytest.raises(InvalidInputError, match="2 rows for a robot with 3"):
        protocol_limits(bad, three)
    back = Protocol.from_json(Protocol(limits=((0.0, 0.01),) * 3, scale_by_exposure=True).to_json())
    assert back.limits == ((0.0, 0.01),) * 3 and back.scale_by_exposure


def test_over_max_tension_counts_and_names_targets():
    tau = np.zeros((4, 2, 3))
    tau[1, 0, 2] = 7.0
    tau[3, 1, 0] = 6.5
    tau[3, 1, 1] = 9.0
    tau[2, 0, 0] = 6.0  # at the limit: not over
    out = over_max_tension(tau, [6.0, 6.0, 6.0])
    assert out == {
        "arrivals": 2,
        "of": 8,
        "fraction": 0.25,
        "targets": [1, 3],
        "per_tendon": [1, 1, 1],
    }
    assert over_max_tension(tau, [6.0] * 3, done=[True, False, True, False])["arrivals"] == 0


def test_three_tendon_tiny_dataset_reports_arrivals_over_max_tension(three, tmp_path, caplog):
    path = generate_dataset(three, "tiny", tmp_path / "t.h5", split="train", workers=1)
    ds = load_dataset(path)
    assert ds.displacements.shape == (6, 3) and ds.tensions.shape == (6, 2, 3)
    info = summarize(path)
    over = over_max_tension(ds.tensions, three.tension_limits, ds.done)
    assert info["targets_over_max_tension"] == over["targets"]
    assert info["arrivals_over_max_tension_count"] == f"{over['arrivals']} of 12"
    if over["arrivals"]:
        assert any("need more than max_tension" in r.message for r in caplog.records)


def test_lab_robot_dataset_carries_rotation_and_retraction(lab, tmp_path):
    """Targets, starts and the MDN's inputs are the robot's whole configuration; each arrival
    has the exposed length of its retraction."""
    path = generate_dataset(lab, "tiny", tmp_path / "lab.h5", split="train", workers=1)
    ds = load_dataset(path)
    assert ds.displacements.shape == (6, 5) and ds.starts.shape == (6, 2, 5)
    assert ds.tensions.shape == (6, 2, 3)
    for i in range(6):
        _, _, ret = lab.split_configuration(ds.displacements[i])
        tip_z = ds.tips[i, :, 2]
        assert np.all(tip_z <= 0.12 - ret + TOL["float64_abs"]["atol"])
        r = np.linalg.norm(ds.points[i].astype(np.float64), axis=-1)
        assert r.max() <= 0.12 - ret + 0.01  # body radius 3 mm plus camera noise
    from riskplan.kinematics.data import read_point_clouds

    data = read_point_clouds(path)
    assert data.displacements.shape[1] == 5


def test_mdn_takes_rotation_and_retraction_as_inputs(lab, tmp_path):
    """A model trained on the lab robot's data set takes its 5-variable configuration, and
    its limits check covers rotation and retraction (a retraction beyond the robot is refused)."""
    from riskplan.kinematics.data import read_point_clouds
    from riskplan.kinematics.training import TrainConfig, train

    path = generate_dataset(lab, "tiny", tmp_path / "lab.h5", split="train", workers=1)
    data = read_point_clouds(path)
    res = train(
        data,
        TrainConfig(n_components=2, hidden=(8,), head_hidden=(8,), epochs=2, val_fraction=0.2),
    )
    model = res.model
    gm = model.predict(np.array([[0.0, 0.001, 0.0, 0.5, 0.06]]))
    assert gm.means.shape[-1] == 3 and model.n_tendons == 5
    np.testing.assert_array_equal(model.limits, lab.configuration_limits)
    with pytest.raises(InvalidInputError):
        model.predict(np.array([[0.0, 0.001, 0.0, 0.5, 0.2]]))
    # the rotation is read as (cos, sin): -pi and pi are one input
    assert model.net.angle_inputs == (3,)
    q = np.array([[0.002, 0.001, 0.0, -np.pi, 0.06], [0.002, 0.001, 0.0, np.pi, 0.06]])
    a = model.predict(q)
    np.testing.assert_allclose(a.means[0], a.means[1], **TOL["float64_exact"])
    # the fused NumPy path and the torch module agree with angle inputs
    import torch

    t = model.mixture(torch.as_tensor(q))
    np.testing.assert_allclose(a.means, t.means.detach().numpy(), **TOL["float32_means"])
    # saved and loaded with its angle input
    from riskplan.kinematics import load_model
    from riskplan.kinematics.model_io import save_model

    save_model(model, tmp_path / "m")
    back = load_model(tmp_path / "m")
    assert back.net.angle_inputs == (3,)
    np.testing.assert_array_equal(back.predict(q).means, a.means)


def test_protocol_json_unknown_key_names_the_closest():
    with pytest.raises(InvalidInputError, match="'grid_level' \\(did you mean 'grid_levels'\\?\\)"):
        Protocol.from_json('{"grid_level": 5}')
