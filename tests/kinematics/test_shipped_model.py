"""The model shipped with riskplan (``load_model("paper")``): provenance, predictions, hash check."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from riskplan.errors import DataFormatError
from riskplan.kinematics import load_model, model_io, resolve_model, shipped_models
from tests.conftest import TOL


def test_paper_is_shipped_with_its_provenance():
    assert "paper" in shipped_models()
    meta = json.loads((resolve_model("paper") / "model.json").read_text())
    prov = meta["provenance"]
    assert prov["dataset"]["preset"] == "paper" and prov["dataset"]["robot"] == "paper"
    assert isinstance(prov["dataset"]["seed"], int)
    for split in ("train", "test"):
        assert re.fullmatch(r"[0-9a-f]{64}", prov["dataset"][f"{split}_content_hash"])
    # the training data named in the provenance are the data the weights were trained on
    assert prov["dataset"]["train_content_hash"] == meta["data"]["content_hash"]
    for key in ("dataset_command", "train_command", "evaluate_command"):
        assert prov[key].startswith("riskplan ")
    assert "--components 10" in prov["train_command"]
    assert np.isfinite(prov["test_nll"]) and prov["test_nll"] < 0
    assert re.fullmatch(r"[0-9a-f]{64}", meta["weights_sha256"])
    assert meta["versions"]["riskplan"]
    # a few hundred kB at most in the package
    size = sum(p.stat().st_size for p in resolve_model("paper").iterdir())
    assert size < 1_000_000


def test_paper_predicts_finite_mixtures_in_limits(rng):
    model = load_model("paper")
    assert model.n_tendons == 4 and model.n_components == 10 and model.robot_name == "paper"
    lim = model.limits
    d = lim[:, 0] + (lim[:, 1] - lim[:, 0]) * rng.random((16, 4))
    gm = model.predict(d)
    w, mu, cov = gm.weights.numpy(), gm.means.numpy(), gm.covariances.numpy()
    assert w.shape == (16, 10) and mu.shape == (16, 10, 3) and cov.shape == (16, 10, 3, 3)
    assert np.all(np.isfinite(w)) and np.all(np.isfinite(mu)) and np.all(np.isfinite(cov))
    np.testing.assert_allclose(w.sum(-1), 1.0, **TOL["float64_exact"])
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    # the robot is 0.2 m long: component means lie within reach of the base
    assert np.all(np.linalg.norm(mu, axis=-1) < 0.3)


def test_shipped_models_are_hash_checked(tmp_path, monkeypatch):
    root = tmp_path / "models"
    shutil.copytree(resolve_model("paper"), root / "paper")
    monkeypatch.setattr(model_io, "_shipped_root", lambda: root)
    assert load_model("paper").n_components == 10
    w = root / "paper" / "weights.pt"
    blob = bytearray(w.read_bytes())
    blob[len(blob) // 2] ^= 0xFF
    w.write_bytes(bytes(blob))
    with pytest.raises(DataFormatError, match="does not match"):
        load_model("paper")


def test_unknown_name_lists_the_shipped_models(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(DataFormatError, match=r"not a shipped model name \(shipped: .*'paper'"):
        load_model("no-such-model")
    # an existing folder wins over a shipped name
    (tmp_path / "paper").mkdir()
    with pytest.raises(DataFormatError, match=r"no model.json"):
        load_model("paper")


def test_cli_predict_with_shipped_model():
    from riskplan.cli import app

    r = CliRunner().invoke(
        app, ["predict", "--model", "paper", "--displacements", "0.01,0,0,0", "--json"]
    )
    assert r.exit_code == 0, r.output
    obj = json.loads(r.output)
    assert obj["n_components"] == 10 and len(obj["means"]) == 10


def test_cli_collision_with_shipped_model(tmp_path):
    import trimesh

    from riskplan.cli import app

    box = trimesh.creation.box(extents=[0.5, 1.0, 1.0])
    box.apply_translation([0.3, 0.0, 0.0])  # slab x >= 0.05 in the robot base frame
    stl = tmp_path / "slab.stl"
    box.export(stl)
    r = CliRunner().invoke(
        app,
        [
            "collision",
            "probability",
            "--env",
            str(stl),
            "--base-pose",
            "identity",
            "--model",
            "paper",
            "-d",
            "0,0,0,0;0.03,0,0,0",
            "--samples",
            "2000",
            "--json",
        ],
    )
    assert r.exit_code == 0, r.output
    rows = json.loads(r.output)
    # straight robot: far from the slab; bent towards +x: its distal part crosses it
    assert rows[0]["probability"] < 0.01 and rows[0]["monte_carlo"] == 0.0
    assert (
        rows[1]["monte_carlo"] > 0.1 and rows[1]["probability"] >= rows[1]["mc_low"]
    )  # eq. 9 bounds it
