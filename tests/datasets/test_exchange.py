"""Point clouds in and out (riskplan.datasets.exchange): export then import is the identity.

Oracle: a generated data set, exported in each cloud format and imported again, gives bit-equal
float64 arrays, float32 points, row digests and the training content hash; bad manifests and
clouds are refused with the file and the field named, before the output exists.
"""

from __future__ import annotations

import csv

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from riskplan.cli import app
from riskplan.datasets import generate_dataset, load_dataset
from riskplan.datasets.exchange import FORMATS, export_dataset, import_dataset, read_cloud
from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.kinematics.data import read_point_clouds
from tests.conftest import TOL

runner = CliRunner()


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    path = tmp_path_factory.mktemp("gen") / "tiny.h5"
    return generate_dataset("paper", "tiny", path, split="train", seed=3, backend="serial")


def _arrays(path):
    with h5py.File(path, "r") as f:
        return {
            k: f[k][...]
            for k in ("displacements", "points", "tips", "starts", "tensions", "done", "row_sha256")
        }


@pytest.mark.parametrize("fmt", FORMATS)
def test_export_then_import_is_bit_exact(generated, tmp_path, fmt):
    man = export_dataset(generated, tmp_path / "out", fmt=fmt)
    assert len(list((tmp_path / "out" / "clouds").glob(f"*.{fmt}"))) == 6 * 2
    back = import_dataset(man, tmp_path / "back.h5")
    a, b = _arrays(generated), _arrays(back)
    for key in a:
        assert a[key].dtype == b[key].dtype, key
        np.testing.assert_array_equal(b[key], a[key], err_msg=key)
    assert read_point_clouds(back).content_hash == read_point_clouds(generated).content_hash
    ds0, ds1 = load_dataset(generated), load_dataset(back)
    for key in ("robot_toml", "robot_name", "protocol", "split", "seed"):
        assert ds1.metadata[key] == ds0.metadata[key], key
    assert ds1.protocol == ds0.protocol


def test_tension_manifest_goes_through_the_robot_model(generated, tmp_path, robot):
    """A manifest of target tensions only: displacements come from the robot model, and the
    model's tensions for them are the manifest's again; tips are the model's at the target."""
    man = export_dataset(generated, tmp_path / "out")
    rows = list(csv.DictReader(man.open()))
    keep = ["config_id", "start_id", "file"] + [f"tension{i}" for i in range(4)]
    # every tendon taut (a slack tendon's displacement is not a function of its zero tension)
    tau = np.array([[0.6 + 0.3 * c, 0.2, 0.4, 0.1 * (c + 1)] for c in range(6)])
    with (tmp_path / "out" / "tau.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(keep)
        for r in rows:
            c = int(r["config_id"])
            w.writerow(
                [r["config_id"], r["start_id"], r["file"], *(repr(float(v)) for v in tau[c])]
            )
    back = load_dataset(import_dataset(tmp_path / "out" / "tau.csv", tmp_path / "tau.h5"))
    np.testing.assert_allclose(
        robot.tensions_for_displacements(back.displacements), tau, **TOL["tension_solve"]
    )
    np.testing.assert_array_equal(back.points, load_dataset(generated).points)
    np.testing.assert_array_equal(back.tensions, np.repeat(tau[:, None], 2, axis=1))
    np.testing.assert_allclose(
        back.tips[:, 1], robot.solve_displacements(back.displacements).tip, **TOL["float64_exact"]
    )
    # a tension beyond the limit is named
    with (tmp_path / "out" / "tau.csv").open("a") as fh:
        for start in (0, 1):
            fh.write(f"99,{start},{rows[0]['file']},{robot.tension_limits[0] * 2},0.1,0.1,0.1\n")
    with pytest.raises(
        InvalidInputError,
        match=r"line \d+, field 'tension0': 19.46 outside the robot's tensions limits \[0, 9.73\] N",
    ):
        import_dataset(tmp_path / "out" / "tau.csv", tmp_path / "tau2.h5")


def _rewrite(man, edit):
    rows = list(csv.reader(man.open()))
    edit(rows)
    with man.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)


def _col(rows, name):
    return rows[0].index(name)


@pytest.mark.parametrize(
    ("case", "match"),
    [
        ("missing_file", r"line 2, field 'file': .*c00000_s0.npy not found"),
        ("missing_column", r"columns d0, d1, d2, d3: d3 missing"),
        ("not_a_number", r"line 3, field 'd1': expected a finite number, got 'abc'"),
        ("two_targets", r"line 3, fields d0..d3: configuration 0 has another target on line 2"),
        ("starts", r"config_id 0: start_id values \[0, 0\]"),
        ("limits", r"line 2, field 'd2': 0.5 outside the robot's displacements limits"),
        ("nan_point", r"c00001_s0.npy: point 7 is not finite"),
        ("millimetres", r"c00002_s1.npy .*beyond the robot's reach.*millimetres"),
        ("count", r"c00003_s0.npy \(manifest line 8\): 100 points, but most clouds have 512"),
    ],
)
def test_bad_manifests_and_clouds_are_named_before_writing(generated, tmp_path, case, match):
    out = tmp_path / "out"
    man = export_dataset(generated, out)
    if case == "missing_file":
        (out / "clouds" / "c00000_s0.npy").unlink()
    elif case == "missing_column":
        _rewrite(man, lambda r: [row.pop(j) for j in [_col(r, "d3")] for row in r])
    elif case == "not_a_number":
        _rewrite(man, lambda r: r[2].__setitem__(_col(r, "d1"), "abc"))
    elif case == "two_targets":
        _rewrite(man, lambda r: r[2].__setitem__(_col(r, "d0"), "0.001234"))
    elif case == "starts":
        _rewrite(man, lambda r: r[2].__setitem__(_col(r, "start_id"), "0"))
    elif case == "limits":
        _rewrite(man, lambda r: [row.__setitem__(_col(r, "d2"), "0.5") for row in r[1:3]])
    elif case == "nan_point":
        p = np.load(out / "clouds" / "c00001_s0.npy")
        p[7, 1] = np.nan
        np.save(out / "clouds" / "c00001_s0.npy", p)
    elif case == "millimetres":
        p = np.load(out / "clouds" / "c00002_s1.npy")
        np.save(out / "clouds" / "c00002_s1.npy", p * 1000)
    elif case == "count":
        p = np.load(out / "clouds" / "c00003_s0.npy")
        np.save(out / "clouds" / "c00003_s0.npy", p[:100])
    target = tmp_path / "bad.h5"
    with pytest.raises((InvalidInputError, DataFormatError), match=match):
        import_dataset(man, target)
    assert not target.exists()
    assert not list(tmp_path.glob(".bad.h5*"))


def test_point_subsets_and_scale(generated, tmp_path):
    out = tmp_path / "out"
    man = export_dataset(generated, out, fmt="csv")
    ds = load_dataset(generated)
    # clouds in millimetres with a different count each: --scale and --points make them fit
    for i, f in enumerate(sorted((out / "clouds").glob("*.csv"))):
        p = read_cloud(f)
        np.savetxt(f, p[: 400 + i].astype(np.float64) * 1000, delimiter=",", fmt="%.9g")
    back = load_dataset(import_dataset(man, tmp_path / "sub.h5", n_points=300, scale=0.001))
    assert back.points.shape == (6, 2, 300, 3)
    # every kept point is one of the original cloud's points (to the mm -> m rounding)
    orig = ds.points[0, 0].astype(np.float64)
    d = np.linalg.norm(back.points[0, 0][:, None].astype(np.float64) - orig[None], axis=-1).min(1)
    np.testing.assert_allclose(d, 0.0, **TOL["float32_rounding"])


def test_cli_export_import(generated, tmp_path):
    res = runner.invoke(
        app, ["dataset", "export", str(generated), "--out", str(tmp_path / "x"), "--format", "pcd"]
    )
    assert res.exit_code == 0, res.output
    res = runner.invoke(
        app,
        [
            "dataset",
            "import",
            str(tmp_path / "x" / "manifest.csv"),
            "--out",
            str(tmp_path / "y.h5"),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "6 configurations x 2 clouds x 512 points" in res.output
    res = runner.invoke(
        app,
        [
            "dataset",
            "import",
            str(tmp_path / "x" / "manifest.csv"),
            "--out",
            str(tmp_path / "y.h5"),
        ],
    )
    assert res.exit_code != 0 and "exists" in str(res.exception)


def test_an_imported_set_trains(generated, tmp_path):
    """Imported clouds go straight into `riskplan model train` (two epochs of a small network)."""
    man = export_dataset(generated, tmp_path / "x", fmt="ply")
    data = import_dataset(man, tmp_path / "imported.h5")
    res = runner.invoke(
        app,
        ["train", "--data", str(data), "--out", str(tmp_path / "model"), "--epochs", "2",
         "-k", "2", "--hidden", "8", "--head-hidden", "", "--val-fraction", "0.2"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert (tmp_path / "model" / "model.json").is_file()
