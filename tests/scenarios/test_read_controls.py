"""Reading control sequences (JSON, CSV/text, the ``selected.npz`` of ``plan tissue``) and
drawing random ones."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.scenarios.controls import read_controls


def test_read_controls_formats(tmp_path, tol):
    a = tmp_path / "a.json"
    a.write_text("[[0.1, 0.2], [0.3, 0.4]]")
    np.testing.assert_allclose(
        read_controls(a, 2), [[0.1, 0.2], [0.3, 0.4]], **tol["float64_exact"]
    )
    b = tmp_path / "b.txt"
    b.write_text("0.1,0.2\n\n0.3,0.4\n")
    np.testing.assert_allclose(
        read_controls(b, 2), [[0.1, 0.2], [0.3, 0.4]], **tol["float64_exact"]
    )
    bad = tmp_path / "c.csv"
    bad.write_text("0.1,0.2\n0.3\n")
    with pytest.raises(DataFormatError):
        read_controls(bad, 2)
    bad.write_text("0.1,0.2,0.3\n")
    with pytest.raises(InvalidInputError):
        read_controls(bad, 2)
    bad.write_text("0.1,nan\n")
    with pytest.raises(InvalidInputError):
        read_controls(bad, 2)
    with pytest.raises(DataFormatError):
        read_controls(tmp_path / "missing.csv", 2)
    j = tmp_path / "d.json"
    j.write_text("{not json")
    with pytest.raises(DataFormatError):
        read_controls(j, 2)


def test_read_controls_npz(tmp_path, tol):
    # the selected.npz of `riskplan plan tissue` replays; a file of several plans is refused
    u = np.array([[0.1, 0.2], [0.3, -0.4], [0.5, 0.0]])
    one = tmp_path / "selected.npz"
    np.savez(one, controls=u, reduced=np.zeros((4, 3)))
    np.testing.assert_allclose(read_controls(one, 2), u, **tol["float64_exact"])
    several = tmp_path / "candidates.npz"
    np.savez(several, controls=u, control_offsets=np.array([0, 1, 3]))
    with pytest.raises(DataFormatError, match="several plans"):
        read_controls(several, 2)
    other = tmp_path / "other.npz"
    np.savez(other, forces=u)
    with pytest.raises(DataFormatError, match="no 'controls' array"):
        read_controls(other, 2)
    fake = tmp_path / "fake.npz"
    fake.write_text("not a zip")
    with pytest.raises(DataFormatError, match=r"fake\.npz"):
        read_controls(fake, 2)


def test_manipulation_random_controls_bad_count():
    from riskplan.scenarios.manipulation import ManipulationScenario

    with pytest.raises(InvalidInputError, match="n_steps"):
        ManipulationScenario().random_controls(-1, seed=0)
    assert ManipulationScenario().random_controls(0, seed=0).shape == (0, 6)
