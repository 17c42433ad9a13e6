"""Robot TOML parsing and validation."""

from __future__ import annotations

import math
from importlib import resources

import numpy as np
import pytest

from riskplan.errors import RobotDescriptionError
from riskplan.robots.description import load_robot_params, parse_robot_toml, read_robot_text
from riskplan.robots.params import params_to_toml, quaternion_to_matrix, rpy_to_matrix
from tests.conftest import TOL

PAPER = resources.files("riskplan").joinpath("data", "paper_robot.toml").read_text()

MINIMAL = """
[backbone]
length = 0.1
outer_radius = 0.002
youngs_modulus = 2e8

[[tendons]]
theta = [0.0]
radius = [0.005]
displacement_limits = [0.0, 0.01]
max_tension = 5.0
"""


def test_paper_parameters():
    p = parse_robot_toml(PAPER)
    b = p.backbone
    assert (
        p.name == "paper"
        and b.length == 0.2
        and b.outer_radius == 0.003
        and b.youngs_modulus == 9.1e7
    )
    np.testing.assert_allclose(b.shear_modulus, 9.1e7 / 2.6, **TOL["float64_bits"])
    assert b.n_steps == 40 and p.disks.count == 9 and len(p.tendons) == 4
    assert p.disks.positions[-1] == pytest.approx(0.2) and p.disks.positions[0] == pytest.approx(
        0.2 / 9
    )
    assert p.tendons[3].theta == (-2.0944, -47.124) and p.tendons[3].max_tension == 16.81
    assert all(t.displacement_limits == (-0.01, 0.04) for t in p.tendons)
    np.testing.assert_allclose(
        b.kbt[0] * 0 + 1.0 / (b.kbt[0] / 0.008), 1.3819, **TOL["quoted_5_digits"]
    )


def test_minimal_defaults():
    p = parse_robot_toml(MINIMAL)
    assert p.name == "robot" and p.backbone.inner_radius == 0.0 and p.disks.count == 0
    assert math.isinf(p.tendons[0].stiffness) and not p.gravity.enabled
    np.testing.assert_array_equal(p.base.matrix, np.eye(3))


def test_toml_round_trip():
    p = parse_robot_toml(PAPER)
    assert parse_robot_toml(params_to_toml(p)) == p
    q = parse_robot_toml(MINIMAL)
    assert parse_robot_toml(params_to_toml(q)) == q


@pytest.mark.parametrize(
    "edit, key",
    [
        (lambda t: t.replace("length = 0.1\n", ""), "backbone.length"),
        (lambda t: t.replace("length = 0.1", "length = -0.1"), "backbone.length"),
        (lambda t: t.replace("length = 0.1", 'length = "long"'), "backbone.length"),
        (
            lambda t: t.replace("youngs_modulus = 2e8", "youngs_modulus = nan"),
            "backbone.youngs_modulus",
        ),
        (lambda t: t.replace("max_tension = 5.0", "max_tension = 0.0"), "tendons[0].max_tension"),
        (lambda t: t.replace("[0.0, 0.01]", "[0.01, 0.0]"), "tendons[0].displacement_limits"),
        (lambda t: t.replace("[0.0, 0.01]", "[0.01]"), "tendons[0].displacement_limits"),
        (lambda t: t.replace("radius = [0.005]", "radius = [0.005, -1.0]"), "tendons[0].radius"),
        (lambda t: t.replace("theta = [0.0]", "theta = []"), "tendons[0].theta"),
        (lambda t: t + "\n[gravity]\nenabled = 1\n", "gravity.enabled"),
        (lambda t: t + "\n[base]\nquaternion = [0, 0, 0]\n", "base.quaternion"),
        (lambda t: t + "\n[base]\nrotation = [[1, 0, 0], [0, 1, 0], [0, 0, 2]]\n", "base.rotation"),
        (
            lambda t: t.replace(
                "youngs_modulus = 2e8", "youngs_modulus = 2e8\nyoungs_modulus_typo = 1"
            ),
            "backbone.youngs_modulus_typo",
        ),
        (
            lambda t: t.replace(
                "youngs_modulus = 2e8", "youngs_modulus = 2e8\npoisson_ratio = 0.7"
            ),
            "backbone.poisson_ratio",
        ),
        (
            lambda t: t.replace(
                "outer_radius = 0.002", "outer_radius = 0.002\ninner_radius = 0.003"
            ),
            "backbone.inner_radius",
        ),
        (lambda t: t.replace("[backbone]", "[backbone_]"), "backbone_"),
        (lambda t: t.split("[[tendons]]")[0], "tendons"),
    ],
)
def test_malformed_names_key(edit, key):
    with pytest.raises(RobotDescriptionError) as info:
        parse_robot_toml(edit(MINIMAL))
    assert info.value.key == key
    assert key in str(info.value)


def test_not_toml():
    with pytest.raises(RobotDescriptionError, match="not valid TOML"):
        parse_robot_toml("[backbone\nlength = 1")


def test_orientations_agree():
    rpy = (0.2, -0.4, 1.3)
    R = rpy_to_matrix(rpy)
    np.testing.assert_allclose(R.T @ R, np.eye(3), **TOL["float64_exact"])
    # quaternion of the same rotation (from the matrix, w > 0 branch)
    w = math.sqrt(1 + np.trace(R)) / 2
    q = [
        w,
        (R[2, 1] - R[1, 2]) / (4 * w),
        (R[0, 2] - R[2, 0]) / (4 * w),
        (R[1, 0] - R[0, 1]) / (4 * w),
    ]
    np.testing.assert_allclose(quaternion_to_matrix(q), R, **TOL["float64_exact"])
    a = parse_robot_toml(MINIMAL + "\n[base]\nrpy = [0.2, -0.4, 1.3]\n")
    b = parse_robot_toml(MINIMAL + f"\n[base]\nquaternion = {[float(v) for v in q]}\n")
    np.testing.assert_allclose(a.base.matrix, b.base.matrix, **TOL["float64_exact"])


def test_file_not_utf8_names_the_file(tmp_path):
    f = tmp_path / "latin1.toml"
    f.write_bytes(
        'name = "r\xf6bot"\n'.encode("latin-1") + MINIMAL.encode()
    )  # used to raise UnicodeDecodeError
    for read in (load_robot_params, read_robot_text):
        with pytest.raises(RobotDescriptionError, match=r"latin1.toml.*not valid UTF-8"):
            read(f)
    with pytest.raises(RobotDescriptionError, match="cannot read"):
        load_robot_params(tmp_path / "missing.toml")


def test_file_read_as_utf8(tmp_path):
    f = tmp_path / "utf8.toml"
    f.write_bytes('name = "r\xf6bot"\n'.encode() + MINIMAL.encode())
    params, text = load_robot_params(f)
    assert params.name == "r\xf6bot" and text.startswith('name = "r\xf6bot"')


def test_bytes_are_not_toml_text():
    with pytest.raises(RobotDescriptionError, match="str"):
        parse_robot_toml(MINIMAL.encode())


@pytest.mark.parametrize(
    "edit, key, match",
    [
        # these took 45 s and 8 GB before a MemoryError: refused at once, saying why
        (lambda t: t.replace("length = 0.1", "length = 1e5"), "backbone.step", "integration steps"),
        (
            lambda t: t.replace("youngs_modulus = 2e8", "youngs_modulus = 2e8\nstep = 1e-9"),
            "backbone.step",
            "integration steps",
        ),
        (lambda t: t + "\n[disks]\ncount = 100000000\n", "disks.count", "10000"),
        (
            lambda t: t.replace("theta = [0.0]", "theta = [" + ", ".join(["0.0"] * 100) + "]"),
            "tendons[0].theta",
            "coefficients",
        ),
    ],
)
def test_absurd_robot_files_are_bounded(edit, key, match):
    with pytest.raises(RobotDescriptionError, match=match) as info:
        parse_robot_toml(edit(MINIMAL))
    assert info.value.key == key


def test_robot_facade_rejects_silently_coerced_input():
    from riskplan.errors import InvalidInputError
    from riskplan.robots import robot_from_toml

    r = robot_from_toml(MINIMAL)
    with pytest.raises(InvalidInputError, match="complex"):
        r.solve_tensions(np.array([1.0 + 1.0j]))
    with pytest.raises(InvalidInputError, match="True or False"):
        r.with_gravity("yes")
