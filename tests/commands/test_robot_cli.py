"""CLI tests for `riskplan robot shape` / `riskplan robot info`."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.robots import load_robot
from tests.conftest import TOL

runner = CliRunner()


def test_shape_json_displacements():
    res = runner.invoke(
        app, ["robot", "shape", "--robot", "paper", "--displacements", "0.01,0,0,0", "--json"]
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert set(out) == {"tip", "backbone", "tensions"}
    ref = load_robot("paper").solve_displacements([0.01, 0, 0, 0])
    np.testing.assert_allclose(out["tip"], ref.tip, **TOL["float64_exact"])
    assert np.array(out["backbone"]).shape == (41, 3) and len(out["tensions"]) == 4


def test_shape_tensions_plot_and_file_robot(tmp_path):
    f = tmp_path / "r.toml"
    f.write_text(load_robot("paper").toml_text())
    png = tmp_path / "s.png"
    res = runner.invoke(
        app, ["robot", "shape", "--robot", str(f), "--tensions", "1,0,0,2", "--plot", str(png)]
    )
    assert res.exit_code == 0, res.output
    assert "tip" in res.output and png.stat().st_size > 1000


def test_shape_bad_input_is_a_clean_error():
    res = runner.invoke(app, ["robot", "shape", "--displacements", "0.05,0,0,0"])
    assert res.exit_code != 0
    assert "0.04" in str(res.exception) or "0.04" in res.output
    res = runner.invoke(app, ["robot", "shape"])
    assert res.exit_code != 0


def test_info_json():
    res = runner.invoke(app, ["robot", "info", "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads(res.output)
    assert (
        d["name"] == "paper"
        and len(d["tendons"]) == 4
        and d["tendons"][3]["max_tension_n"] == 16.81
    )


INEXTENSIBLE = """
name = "four"
[backbone]
length = 0.2
outer_radius = 0.003
youngs_modulus = 9.1e7
""" + "".join(
    f"""
[[tendons]]
theta = [{a}]
radius = [0.008]
displacement_limits = [-0.01, 0.04]
max_tension = 10
"""
    for a in (0.0, 1.5707963267948966, 3.141592653589793, 4.71238898038469)
)


def _strict_json(text):
    def reject(const):
        raise AssertionError(f"non-standard JSON constant {const}")

    return json.loads(text, parse_constant=reject)


def test_info_json_is_strict_for_inextensible_tendons(tmp_path):
    # no `stiffness` key: inextensible (inf), which used to print `Infinity` (not JSON)
    f = tmp_path / "four.toml"
    f.write_text(INEXTENSIBLE)
    res = runner.invoke(app, ["robot", "info", "--robot", str(f), "--json"])
    assert res.exit_code == 0, res.output
    assert "Infinity" not in res.output
    d = _strict_json(res.output)
    assert [t["stiffness_n_per_m"] for t in d["tendons"]] == [None] * 4
    assert d["tendons"][0]["max_tension_n"] == 10
    res = runner.invoke(app, ["robot", "info", "--robot", str(f)])
    assert res.exit_code == 0 and "k inf N/m" in res.output


def test_shape_json_is_strict():
    res = runner.invoke(app, ["robot", "shape", "--tensions", "1,0,0,0", "--json"])
    assert res.exit_code == 0, res.output
    assert len(_strict_json(res.output)["tip"]) == 3


def test_finite_or_none():
    from riskplan.commands.robot import _dumps, _finite_or_none

    assert _finite_or_none({"a": [1.0, float("inf"), (float("nan"), 2)], "b": "x", "c": True}) == {
        "a": [1.0, None, [None, 2]],
        "b": "x",
        "c": True,
    }
    assert _dumps({"k": np.float64("inf")}) == '{"k": null}'


def test_info_help_documents_null():
    res = runner.invoke(app, ["robot", "info", "--help"])
    assert res.exit_code == 0 and "null" in res.output


def test_robot_file_not_utf8_is_a_clean_error(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_bytes(b'name = "x"\n\xff\xfe\n')
    res = runner.invoke(app, ["robot", "info", "--robot", str(f)])
    assert res.exit_code != 0
    assert "bad.toml" in str(res.exception) and "UTF-8" in str(res.exception)
