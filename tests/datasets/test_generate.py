"""Generation: same data on every backend, resumed == uninterrupted bit for bit, bad input."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import h5py
import numpy as np
import pytest

from riskplan.datasets import (
    PRESETS,
    generate_dataset,
    load_dataset,
    simulate_target,
    target_configurations,
)
from riskplan.datasets.storage import partial_path
from riskplan.errors import DataFormatError, InvalidInputError
from tests.conftest import TOL

TINY = PRESETS["tiny"]
ARRAYS = ("displacements", "points", "tips", "starts", "tensions", "done")


def _arrays(path):
    with h5py.File(path, "r") as f:
        return {k: f[k][...] for k in ARRAYS}


def _assert_same(a, b):
    for k in ARRAYS:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@pytest.fixture(scope="module")
def reference(tmp_path_factory, robot):
    """The tiny training split generated serially in one go."""
    p = tmp_path_factory.mktemp("ref") / "ref.h5"
    generate_dataset(robot, "tiny", p, split="train", seed=3, backend="serial")
    return p


def test_reference_file_complete_and_consistent(reference, robot):
    ds = load_dataset(reference)
    assert ds.complete and ds.n_configs == TINY.n_train
    assert ds.points.shape == (TINY.n_train, TINY.n_starts, TINY.n_points, 3)
    np.testing.assert_array_equal(
        ds.displacements, target_configurations(TINY, robot.displacement_limits, "train")
    )
    assert ds.metadata["robot_toml"] == robot.toml_text() and ds.metadata["seed"] == 3
    assert ds.robot.n_tendons == 4
    assert not partial_path(reference).exists()


def test_local_backend_matches_serial(reference, robot, tmp_path):
    p = generate_dataset(
        robot,
        "tiny",
        tmp_path / "local.h5",
        split="train",
        seed=3,
        backend="local",
        workers=2,
        chunksize=1,
        min_parallel_clouds=0,
    )
    _assert_same(_arrays(p), _arrays(reference))


def test_ray_backend_matches_serial(robot, tmp_path):
    pytest.importorskip("ray")
    a = generate_dataset(robot, "tiny", tmp_path / "s.h5", split="test", seed=3, backend="serial")
    b = generate_dataset(
        robot, "tiny", tmp_path / "r.h5", split="test", seed=3, backend="ray", workers=2
    )
    _assert_same(_arrays(a), _arrays(b))


def test_resume_after_stop_is_bit_identical(reference, robot, tmp_path):
    out = tmp_path / "resumed.h5"
    got = generate_dataset(robot, "tiny", out, split="train", seed=3, backend="serial", max_new=2)
    assert got == partial_path(out) and not out.exists()
    assert load_dataset(got).done.sum() == 2
    got = generate_dataset(robot, "tiny", out, split="train", seed=3, backend="serial", max_new=1)
    assert load_dataset(got).done.sum() == 3
    got = generate_dataset(
        robot, "tiny", out, split="train", seed=3, backend="local", workers=2, min_parallel_clouds=0
    )
    assert got == out and not partial_path(out).exists()
    _assert_same(_arrays(out), _arrays(reference))


def test_resume_after_kill_is_bit_identical(reference, robot, tmp_path):
    """A process SIGKILLed in the middle of a generation, then resumed."""
    out = tmp_path / "killed.h5"
    script = textwrap.dedent(
        f"""
        import os, signal
        from riskplan.datasets import generate_dataset
        def progress(done, total):
            if done >= 3:
                os.kill(os.getpid(), signal.SIGKILL)
        generate_dataset("paper", "tiny", {str(out)!r}, split="train", seed=3, backend="serial", progress=progress)
        """
    )
    r = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert r.returncode == -9, r.stderr.decode()
    assert partial_path(out).exists() and not out.exists()
    assert load_dataset(partial_path(out)).done.sum() == 3
    generate_dataset(robot, "tiny", out, split="train", seed=3, backend="serial")
    _assert_same(_arrays(out), _arrays(reference))


def test_resume_with_other_settings_refused(robot, tmp_path):
    out = tmp_path / "x.h5"
    generate_dataset(robot, "tiny", out, split="train", seed=3, backend="serial", max_new=1)
    with pytest.raises(DataFormatError, match="seed"):
        generate_dataset(robot, "tiny", out, split="train", seed=4, backend="serial")
    with pytest.raises(DataFormatError, match="protocol"):
        generate_dataset(
            robot, TINY.replace(n_starts=3), out, split="train", seed=3, backend="serial"
        )
    # overwrite starts afresh
    p = generate_dataset(
        robot, "tiny", out, split="train", seed=4, backend="serial", overwrite=True
    )
    assert load_dataset(p).metadata["seed"] == 4


def test_complete_file_is_not_regenerated(reference, robot):
    before = os.stat(reference).st_mtime_ns
    assert (
        generate_dataset(robot, "tiny", reference, split="train", seed=3, backend="serial")
        == reference
    )
    assert os.stat(reference).st_mtime_ns == before


def test_train_and_test_differ(reference, robot, tmp_path):
    te = generate_dataset(robot, "tiny", tmp_path / "te.h5", split="test", seed=3, backend="serial")
    a, b = load_dataset(reference), load_dataset(te)
    assert not set(map(tuple, a.displacements)) & set(map(tuple, b.displacements))
    assert not np.any(np.isin(a.starts, b.starts))


def test_clouds_lie_on_the_robot_and_spread_with_the_path(robot):
    """Points are within the body (plus noise) around the arrival backbone; arrivals differ by start."""
    target = np.array([0.02, 0.0, 0.01, 0.0])
    r = simulate_target(robot, PRESETS["small"], target, seed=11, return_shapes=True)
    shape = r["shape"]
    R_disk = robot.params.disks.radius
    r_tube = robot.params.backbone.outer_radius
    for j in range(len(r["points"])):
        pts = r["points"][j].astype(np.float64)
        # distance of each point to the backbone polyline of its own arrival shape
        bb = shape.positions[j]
        a, b = bb[:-1], bb[1:]
        ab = b - a
        t = np.clip(
            np.einsum("pki,ki->pk", pts[:, None, :] - a, ab) / np.einsum("ki,ki->k", ab, ab), 0, 1
        )
        d = np.linalg.norm(pts[:, None, :] - (a + t[..., None] * ab), axis=-1).min(1)
        assert d.max() < np.hypot(R_disk, robot.params.disks.thickness / 2) + 5 * 0.0005
        assert np.mean(d < r_tube + 3 * 0.0005) > 0.3  # much of the cloud is the backbone tube
        # both cameras contribute: points on both sides (camera axis is y)
        rel = (
            pts[:, 1] - np.interp(pts[:, 2], bb[:, 2], bb[:, 1])
            if np.all(np.diff(bb[:, 2]) > 0)
            else pts[:, 1] - bb[:, 1].mean()
        )
        assert np.mean(rel > 0) > 0.2 and np.mean(rel < 0) > 0.2
    np.testing.assert_allclose(r["tips"], shape.positions[:, -1], rtol=0, atol=0)
    spread = np.linalg.norm(r["tips"] - r["tips"].mean(0), axis=1)
    assert spread.max() > 1e-4  # path dependence shows (play 0.5 mm per tendon)


def test_clouds_in_base_frame_whatever_the_base_pose(robot):
    """Moving the robot's base in the world does not change its data (cameras ride with the base)."""
    moved = robot.with_base_pose((0.1, -0.2, 0.3), rpy=(0.3, -0.2, 0.5))
    target = np.array([0.0, 0.02, 0.0, 0.01])
    a = simulate_target(robot, TINY, target, seed=5)
    b = simulate_target(moved, TINY, target, seed=5)
    np.testing.assert_allclose(b["tips"], a["tips"], **TOL["float64_abs"])
    # float32 clouds: equal up to float64 round-off crossing a float32 rounding boundary
    np.testing.assert_allclose(b["points"], a["points"], **TOL["float32_rounding"])


def test_bad_input(robot, tmp_path):
    with pytest.raises(InvalidInputError, match="preset"):
        generate_dataset(robot, "enormous", tmp_path / "a.h5")
    with pytest.raises(InvalidInputError, match="split"):
        generate_dataset(robot, "tiny", tmp_path / "a.h5", split="validation")
    with pytest.raises(InvalidInputError, match="backend"):
        generate_dataset(robot, "tiny", tmp_path / "a.h5", backend="gpu")
    with pytest.raises(InvalidInputError, match="target"):
        simulate_target(robot, TINY, [0.05, 0.0, 0.0, 0.0], seed=0)
    with pytest.raises(InvalidInputError, match="target"):
        simulate_target(robot, TINY, [0.0, 0.0, 0.0], seed=0)
    bad = tmp_path / "bad.h5"
    bad.write_text("not hdf5")
    with pytest.raises(DataFormatError, match="HDF5"):
        generate_dataset(robot, "tiny", bad, backend="serial")


def test_overwrite_keeps_the_finished_file_until_the_new_one_is_complete(
    reference, robot, tmp_path
):
    out = tmp_path / "o.h5"
    out.write_bytes(reference.read_bytes())
    before = out.read_bytes()

    def stop(done, total):
        if done >= 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate_dataset(
            robot,
            "tiny",
            out,
            split="train",
            seed=5,
            backend="serial",
            overwrite=True,
            progress=stop,
        )
    assert out.read_bytes() == before  # it used to be deleted before the new run started
    assert partial_path(out).exists() and not out.with_name("o.h5.lock").exists()
    generate_dataset(robot, "tiny", out, split="train", seed=5, backend="serial", overwrite=True)
    assert int(load_dataset(out).metadata["seed"]) == 5


def test_bad_workers_leave_no_partial_and_a_second_writer_is_refused(robot, tmp_path):
    out = tmp_path / "w.h5"
    for w in (-1, 0, 1.5, True):
        with pytest.raises(InvalidInputError, match="workers"):
            generate_dataset(robot, "tiny", out, workers=w)
    assert not partial_path(out).exists() and not out.exists()
    # another live process holds the lock: refused, its partial file untouched
    lock = out.with_name("w.h5.lock")
    lock.write_text(f"{os.getppid()}\n")
    with pytest.raises(InvalidInputError, match=rf"another process \(pid {os.getppid()}"):
        generate_dataset(robot, "tiny", out, backend="serial", max_new=1)
    assert not partial_path(out).exists()
    # a lock left by a dead process is taken over
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    lock.write_text(dead.stdout)
    generate_dataset(robot, "tiny", out, backend="serial", max_new=1)
    assert partial_path(out).exists() and not lock.exists()
