import json

import numpy as np
import pytest
import torch

from riskplan.errors import DataFormatError
from riskplan.kinematics import load_model, save_model
from riskplan.kinematics.model_io import META_NAME, WEIGHTS_NAME, check_robot


class _Robot:
    def __init__(self, toml, n=2, name="r"):
        self._toml, self.n_tendons, self.name = toml, n, name

    def toml_text(self):
        return self._toml


def test_roundtrip_identical_predictions(trained, rng, tmp_path):
    res, out = trained
    loaded = load_model(out)
    d = rng.uniform(-0.005, 0.035, size=(11, 2))
    a, b = res.model.predict(d), loaded.predict(d)
    for name in ("weights", "means", "precision_cholesky"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    assert loaded.n_components == 2 and loaded.n_tendons == 2
    np.testing.assert_array_equal(loaded.limits, res.model.limits)
    meta = json.loads((out / META_NAME).read_text())
    for key in (
        "versions",
        "architecture",
        "normalisation",
        "robot",
        "data",
        "training",
        "weights_sha256",
    ):
        assert key in meta
    assert meta["data"]["content_hash"] == res.model.metadata["data"]["content_hash"]
    # save again from the loaded model: same files
    save_model(loaded, tmp_path / "again")
    c = load_model(tmp_path / "again").predict(d)
    assert torch.equal(c.means, a.means)
    assert json.loads((tmp_path / "again" / META_NAME).read_text())["format_version"] == 1


def test_other_robot_rejected(trained):
    _, out = trained
    m = load_model(out)
    load_model(out, robot=_Robot(m.robot_toml))
    with pytest.raises(DataFormatError, match="different description"):
        load_model(out, robot=_Robot('name = "another"\n'))
    with pytest.raises(DataFormatError, match="tendons"):
        check_robot(m, _Robot(m.robot_toml, n=4))


def _copy(src, dst):
    dst.mkdir()
    for name in (META_NAME, WEIGHTS_NAME):
        (dst / name).write_bytes((src / name).read_bytes())
    return dst


def test_corrupted_files_rejected(trained, tmp_path):
    _, out = trained
    m = _copy(out, tmp_path / "a")
    w = (m / WEIGHTS_NAME).read_bytes()
    (m / WEIGHTS_NAME).write_bytes(w[:-10] + bytes(10))
    with pytest.raises(DataFormatError, match="SHA-256"):
        load_model(m)
    m = _copy(out, tmp_path / "b")
    (m / META_NAME).write_text((m / META_NAME).read_text()[:100])
    with pytest.raises(DataFormatError, match="corrupted"):
        load_model(m)
    m = _copy(out, tmp_path / "c")
    meta = json.loads((m / META_NAME).read_text())
    del meta["normalisation"]
    (m / META_NAME).write_text(json.dumps(meta))
    with pytest.raises(DataFormatError, match="normalisation"):
        load_model(m)
    m = _copy(out, tmp_path / "d")
    meta = json.loads((m / META_NAME).read_text())
    meta["architecture"]["n_components"] = 3  # weights of a K=2 network
    (m / META_NAME).write_text(json.dumps(meta))
    with pytest.raises(DataFormatError, match="architecture"):
        load_model(m)
    m = _copy(out, tmp_path / "e")
    (m / WEIGHTS_NAME).unlink()
    with pytest.raises(DataFormatError, match="missing"):
        load_model(m)
    with pytest.raises(DataFormatError, match="not a model folder"):
        load_model(tmp_path / "nothing")


def test_roundtrip_float32_model(synth_small, rng, tmp_path):
    from riskplan.kinematics.data import read_point_clouds
    from riskplan.kinematics.training import TrainConfig, train
    from tests.kinematics.conftest import FAST

    res = train(
        read_point_clouds(synth_small),
        TrainConfig(n_components=3, epochs=2, dtype="float32", **FAST),
        out=tmp_path / "m",
    )
    loaded = load_model(tmp_path / "m")
    assert next(loaded.net.parameters()).dtype == torch.float32
    d = rng.uniform(0.0, 0.03, size=(5, 2))
    for name in ("weights", "means", "precision_cholesky"):
        assert torch.equal(getattr(res.model.predict(d), name), getattr(loaded.predict(d), name))
        assert torch.equal(
            getattr(res.model.predict(d, dtype=torch.float32), name),
            getattr(loaded.predict(d, dtype=torch.float32), name),
        )


def test_model_of_the_paper_robot(tmp_path, rng):
    """Data made with a real robot file: limits and ``model.robot`` come from that robot."""
    from riskplan.errors import InvalidInputError
    from riskplan.kinematics.data import read_point_clouds, write_synthetic_dataset
    from riskplan.kinematics.training import TrainConfig, train
    from riskplan.robots import load_robot

    robot = load_robot("paper")
    lim = robot.displacement_limits
    d = rng.uniform(lim[:, 0], lim[:, 1], size=(8, robot.n_tendons))
    pts = rng.normal(size=(8, 1, 16, 3)) * 0.01
    path = write_synthetic_dataset(
        tmp_path / "p.h5", d, pts, robot_toml=robot.toml_text(), robot_name=robot.name
    )
    data = read_point_clouds(path)
    np.testing.assert_array_equal(data.limits, lim)
    train(
        data, TrainConfig(n_components=2, epochs=1, hidden=(8,), head_hidden=()), out=tmp_path / "m"
    )
    m = load_model(tmp_path / "m", robot=robot)
    assert m.robot.name == "paper" and m.robot.n_tendons == m.n_tendons
    m.predict(lim[:, 1])  # the robot's own limits are accepted, slightly beyond them is not
    with pytest.raises(InvalidInputError, match="limits"):
        m.predict(lim[:, 1] + 1e-4)


def _edited(out, dst, edit):
    m = _copy(out, dst)
    meta = json.loads((m / META_NAME).read_text())
    edit(meta)
    (m / META_NAME).write_text(json.dumps(meta))
    return m


@pytest.mark.parametrize(
    "edit, match",
    [
        (
            lambda m: m["normalisation"].update(output_scale=[0.0, 1.0, 1.0]),
            "output_scale must be > 0",
        ),
        (
            lambda m: m["normalisation"].update(output_scale=[float("nan"), 1.0, 1.0]),
            "output_scale contains NaN",
        ),
        (lambda m: m["normalisation"].update(input_scale=[-1.0, 1.0]), "input_scale must be > 0"),
        (
            lambda m: m["normalisation"].update(output_centre=[float("inf"), 0.0, 0.0]),
            "output_centre",
        ),
        (lambda m: m["normalisation"].update(input_mean=[float("nan"), 0.0]), "input_mean"),
        (
            lambda m: m["robot"].update(displacement_limits=[[0.04, -0.01], [-0.01, 0.04]]),
            "displacement_limits",
        ),
        (
            lambda m: m["robot"].update(displacement_limits=[[float("nan"), 0.04], [-0.01, 0.04]]),
            "displacement_limits",
        ),
        (lambda m: m["architecture"].update(hidden=[2_000_000_000]), "hidden"),
        (lambda m: m["architecture"].update(hidden=[60000, 60000]), "parameters"),
        (lambda m: m["architecture"].update(n_components=-1), "n_components"),
        (lambda m: m["architecture"].update(n_inputs="2"), "n_inputs"),
        (lambda m: m["architecture"].update(dtype="int8"), "dtype"),
    ],
)
def test_every_number_in_model_json_is_checked(trained, tmp_path, edit, match):
    # output_scale = 0 or NaN used to make predict return NaN with exit code 0
    _, out = trained
    with pytest.raises(DataFormatError, match=match):
        load_model(_edited(out, tmp_path / "m", edit))


def test_non_finite_weights_rejected(trained, tmp_path):
    import hashlib
    import io

    _, out = trained
    m = _copy(out, tmp_path / "w")
    state = torch.load(m / WEIGHTS_NAME, weights_only=True)
    key = next(k for k, v in state.items() if v.is_floating_point())
    state[key] = state[key].clone()
    state[key].view(-1)[0] = float("nan")
    buf = io.BytesIO()
    torch.save(state, buf)
    (m / WEIGHTS_NAME).write_bytes(buf.getvalue())
    meta = json.loads((m / META_NAME).read_text())
    meta["weights_sha256"] = hashlib.sha256(
        buf.getvalue()
    ).hexdigest()  # a consistent, but broken, model
    (m / META_NAME).write_text(json.dumps(meta))
    with pytest.raises(DataFormatError, match="NaN"):
        load_model(m)
