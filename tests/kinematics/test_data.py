import h5py
import numpy as np
import pytest

from riskplan.errors import DataFormatError
from riskplan.kinematics.data import check_compatible, content_hash, read_point_clouds
from tests.kinematics.conftest import make_synthetic


def test_read_roundtrip(tmp_path):
    p = make_synthetic(tmp_path / "a.h5", 6, seed=0, starts=2, points=16)
    with h5py.File(p) as f:
        d, pts = f["displacements"][...], f["points"][...]
    data = read_point_clouds(p)
    np.testing.assert_array_equal(data.displacements, d)
    np.testing.assert_array_equal(data.points, pts.reshape(6, 32, 3))
    assert data.n_configs == 6 and data.n_tendons == 2 and data.n_points == 32
    assert data.content_hash == content_hash(d, pts.reshape(6, 32, 3))
    assert data.limits.shape == (2, 2)


def test_only_done_configurations_are_read(tmp_path):
    p = make_synthetic(tmp_path / "a.h5", 6, seed=0, starts=1, points=4)
    with h5py.File(p, "r+") as f:
        f["done"][...] = [True, False, True, True, False, True]
        d = f["displacements"][...]
    data = read_point_clouds(p)
    np.testing.assert_array_equal(data.displacements, d[[0, 2, 3, 5]])


def test_bad_files(tmp_path):
    with pytest.raises(DataFormatError, match="no such file"):
        read_point_clouds(tmp_path / "missing.h5")
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5 at all")
    with pytest.raises(DataFormatError, match="HDF5"):
        read_point_clouds(junk)
    p = make_synthetic(tmp_path / "a.h5", 4, seed=0, starts=1, points=4)
    with h5py.File(p, "r+") as f:
        f.attrs["format"] = "something-else"
    with pytest.raises(DataFormatError, match="format"):
        read_point_clouds(p)
    p = make_synthetic(tmp_path / "b.h5", 4, seed=0, starts=1, points=4)
    with h5py.File(p, "r+") as f:
        del f["points"]
        f["points"] = np.zeros((3, 1, 4, 3), dtype=np.float32)  # 3 clouds for 4 configurations
    with pytest.raises(DataFormatError, match="points has shape"):
        read_point_clouds(p)
    p = make_synthetic(tmp_path / "c.h5", 4, seed=0, starts=1, points=4)
    with h5py.File(p, "r+") as f:
        f["points"][1, 0, 2, 1] = np.nan
    with pytest.raises(DataFormatError, match="NaN"):
        read_point_clouds(p)


def test_check_compatible(tmp_path):
    a = read_point_clouds(make_synthetic(tmp_path / "a.h5", 4, seed=0, starts=1, points=4))
    b = read_point_clouds(
        make_synthetic(tmp_path / "b.h5", 4, seed=1, starts=1, points=4, toml='name = "x"\n')
    )
    check_compatible(a, a)
    with pytest.raises(DataFormatError, match="differs"):
        check_compatible(a, b)
    with pytest.raises(DataFormatError, match="tendons"):
        check_compatible({"robot_toml": a.robot_toml, "n_tendons": 4}, a)
