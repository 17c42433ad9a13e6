"""HDF5 storage: round trip, schema validation, clear errors for foreign files."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from riskplan.datasets import load_dataset, storage
from riskplan.errors import DataFormatError
from tests.conftest import TOL


def _write(path, rng, C=3, S=2, P=5, m=4, complete=True):
    disp = rng.uniform(-0.01, 0.04, (C, m))
    f = storage.create_file(
        path,
        displacements=disp,
        n_starts=S,
        n_points=P,
        robot_toml="name = 'x'\n",
        robot_name="x",
        protocol_json='{"name": "custom"}',
        split="train",
        seed=7,
    )
    rows = []
    with f:
        for i in range(C if complete else C - 1):
            r = (
                rng.normal(size=(S, P, 3)).astype(np.float32),
                rng.normal(size=(S, 3)),
                rng.normal(size=(S, m)),
                rng.random((S, m)),
            )
            storage.write_config(f, i, *r)
            rows.append(r)
        if complete:
            storage.mark_complete(f)
    return disp, rows


def test_round_trip(tmp_path, rng):
    p = tmp_path / "d.h5"
    disp, rows = _write(p, rng)
    ds = load_dataset(p)
    np.testing.assert_array_equal(ds.displacements, disp)
    for i, (pts, tips, starts, tens) in enumerate(rows):
        np.testing.assert_array_equal(ds.points[i], pts)
        np.testing.assert_array_equal(ds.tips[i], tips)
        np.testing.assert_array_equal(ds.starts[i], starts)
        np.testing.assert_array_equal(ds.tensions[i], tens)
        np.testing.assert_array_equal(ds.cloud(i), pts.reshape(-1, 3))
    assert ds.points.dtype == np.float32 and ds.points.shape == (3, 2, 5, 3)
    assert ds.complete and ds.n_configs == 3 and ds.n_starts == 2 and ds.n_points == 5
    md = ds.metadata
    assert md["format"] == "riskplan-dataset" and md["format_version"] == 1 and md["seed"] == 7
    assert (
        md["robot_toml"] == "name = 'x'\n"
        and md["protocol"] == {"name": "custom"}
        and md["split"] == "train"
    )
    assert isinstance(md["riskplan_version"], str) and isinstance(md["created"], str)
    spread = ds.tip_spread()
    d = ds.tips - ds.tips.mean(1, keepdims=True)
    np.testing.assert_allclose(spread, np.sqrt((d**2).sum(-1).mean(-1)), **TOL["float64_exact"])


def test_incomplete_file_reads_with_done_flags(tmp_path, rng):
    p = tmp_path / "d.h5"
    _write(p, rng, complete=False)
    ds = load_dataset(p)
    assert not ds.complete
    np.testing.assert_array_equal(ds.done, [True, True, False])


@pytest.mark.parametrize(
    "damage, match",
    [
        (lambda f: f.attrs.__setitem__("format", "something-else"), "format"),
        (lambda f: f.attrs.__setitem__("format_version", 99), "format_version"),
        (lambda f: f.__delitem__("tips"), "tips"),
        (lambda f: f.attrs.__delitem__("robot_toml"), "robot_toml"),
        (lambda f: f.attrs.__setitem__("protocol", "{not json"), "protocol"),
        (
            lambda f: (
                f.__delitem__("starts"),
                f.create_dataset("starts", data=np.zeros((3, 2, 5))),
            ),
            "starts",
        ),
    ],
)
def test_damaged_files_raise_data_format_error(tmp_path, rng, damage, match):
    p = tmp_path / "d.h5"
    _write(p, rng)
    with h5py.File(p, "r+") as f:
        damage(f)
    with pytest.raises(DataFormatError, match=match):
        load_dataset(p)


def test_not_hdf5_or_missing(tmp_path):
    p = tmp_path / "x.h5"
    p.write_text("hello")
    with pytest.raises(DataFormatError, match="HDF5"):
        load_dataset(p)
    with pytest.raises(DataFormatError, match="no such file"):
        load_dataset(tmp_path / "nope.h5")
    q = tmp_path / "other.h5"
    with h5py.File(q, "w") as f:
        f["a"] = 1
    with pytest.raises(DataFormatError, match="format"):
        load_dataset(q)


def test_nonfinite_points_rejected(tmp_path, rng):
    p = tmp_path / "d.h5"
    _write(p, rng)
    with h5py.File(p, "r+") as f:
        f["points"][0, 0, 0, 0] = np.nan
    with pytest.raises(DataFormatError, match="NaN"):
        load_dataset(p)


def test_flipped_bytes_in_points_are_detected(tmp_path, rng):
    # a real on-disk corruption: flip bits in the raw bytes of configuration 1's points
    p = tmp_path / "d.h5"
    _write(p, rng)
    with h5py.File(p, "r") as f:
        offset = f["points"].id.get_offset()
        row = f["points"][0].nbytes
    raw = bytearray(p.read_bytes())
    raw[offset + row + 3] ^= 0x40  # an exponent bit of a float32 of configuration 1
    p.write_bytes(bytes(raw))
    with pytest.raises(DataFormatError, match=r"SHA-256 digest \(first \[1\]\)"):
        load_dataset(p)


def test_points_beyond_the_robots_reach_are_rejected(tmp_path, rng):
    # digests consistent (written that way), but points kilometres away from a 0.2 m robot
    from riskplan.robots import load_robot

    toml = load_robot("paper").toml_text()
    disp = rng.uniform(-0.01, 0.04, (2, 4))
    p = tmp_path / "d.h5"
    with storage.create_file(
        p,
        displacements=disp,
        n_starts=1,
        n_points=4,
        robot_toml=toml,
        robot_name="paper",
        protocol_json="{}",
        split="train",
        seed=0,
    ) as f:
        storage.write_config(
            f,
            0,
            rng.normal(scale=0.01, size=(1, 4, 3)),
            np.zeros((1, 3)),
            np.zeros((1, 4)),
            np.zeros((1, 4)),
        )
        far = np.full((1, 4, 3), 0.01)
        far[0, 2] = [1500.0, 0.0, 0.0]
        storage.write_config(f, 1, far, np.zeros((1, 3)), np.zeros((1, 4)), np.zeros((1, 4)))
        storage.mark_complete(f)
    with pytest.raises(DataFormatError, match=r"configuration 1 lies 1500 m .* reach"):
        load_dataset(p)


def test_string_typed_arrays_and_files_without_digests(tmp_path, rng, caplog):
    p = tmp_path / "d.h5"
    _write(p, rng)
    with h5py.File(p, "r+") as f:
        del f["displacements"]
        f.create_dataset("displacements", data=np.full((3, 4), "x", dtype="S1"))
    with pytest.raises(DataFormatError, match="displacements has dtype"):
        load_dataset(p)
    # files written before digests existed still load, with a warning
    q = tmp_path / "old.h5"
    _write(q, rng)
    with h5py.File(q, "r+") as f:
        del f[storage.HASHES]
    with caplog.at_level("WARNING"):
        assert load_dataset(q).complete
    assert "no row digests" in caplog.text
