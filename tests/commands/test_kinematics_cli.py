import json

from typer.testing import CliRunner

from riskplan.cli import app

runner = CliRunner()


def test_train_predict_evaluate_cli(synth_paths, tmp_path):
    train, test = synth_paths
    out = tmp_path / "m"
    r = runner.invoke(
        app,
        [
            "model",  # the group; the old spellings below are hidden aliases
            "train",
            "--data",
            str(train),
            "--components",
            "2",
            "--out",
            str(out),
            "--epochs",
            "2",
            "--hidden",
            "16,16",
            "--head-hidden",
            "8",
        ],
    )
    assert r.exit_code == 0, r.output
    assert (out / "model.json").is_file()
    r = runner.invoke(
        app,
        [
            "train",
            "--data",
            str(train),
            "--components",
            "2",
            "--out",
            str(out),
            "--epochs",
            "3",
            "--hidden",
            "16,16",
            "--head-hidden",
            "8",
            "--resume",
        ],
    )
    assert r.exit_code == 0, r.output
    assert "3 epochs" in r.output
    r = runner.invoke(
        app, ["predict", "--model", str(out), "--displacements", "0.01,0.02;0.0,0.0", "--json"]
    )
    assert r.exit_code == 0, r.output
    obj = json.loads(r.output)
    assert len(obj["weights"]) == 2 and len(obj["means"][0]) == 2
    r = runner.invoke(
        app,
        [
            "evaluate",
            "--model",
            str(out),
            "--data",
            str(test),
            "--out",
            str(tmp_path / "ev"),
            "--samples",
            "512",
        ],
    )
    assert r.exit_code == 0, r.output
    ev = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert set(ev["calibration"]) == {"0.5", "0.9", "0.95"}
    assert (tmp_path / "ev" / "fig5_samples_vs_truth.png").is_file()
    assert (tmp_path / "ev" / "fig5_samples_vs_truth.html").is_file()


def test_predict_bad_input_is_clean_error(trained):
    from riskplan.errors import InvalidInputError

    _, out = trained
    r = runner.invoke(app, ["predict", "--model", str(out), "--displacements", "0.01,0.02,0.03"])
    assert r.exit_code != 0
    assert isinstance(r.exception, InvalidInputError)


def test_sweep_cli(synth_small, tmp_path):
    out = tmp_path / "sw"
    r = runner.invoke(
        app,
        [
            "sweep",
            "--data",
            str(synth_small),
            "--test",
            str(synth_small),
            "--components",
            "1,2",
            "--out",
            str(out),
            "--epochs",
            "2",
            "--hidden",
            "8",
            "--head-hidden",
            "",
        ],
    )
    assert r.exit_code == 0, r.output
    obj = json.loads((out / "sweep.json").read_text())
    assert obj["components"] == [1, 2] and obj["recommended_components"] in (1, 2)
    assert (out / "fig4_nll_vs_k.png").is_file()


def test_train_on_missing_data_is_clean_error(tmp_path):
    from riskplan.errors import DataFormatError

    r = runner.invoke(
        app, ["train", "--data", str(tmp_path / "none.h5"), "--out", str(tmp_path / "m")]
    )
    assert r.exit_code != 0 and isinstance(r.exception, DataFormatError)
    assert not (tmp_path / "m").exists()


def test_predict_bad_files_are_clean_errors(trained, tmp_path):
    from riskplan.errors import InvalidInputError

    _, out = trained
    bad = {
        "a.npy": b"\x93NUMPY garbage",
        "b.json": b"{not json",
        "c.csv": b"0.01,abc\n",
        "d.json": b'[["x", 1]]',
        "e.csv": "0.01,0.02\n".encode("utf-16"),
    }
    for name, content in bad.items():
        (tmp_path / name).write_bytes(content)
        r = runner.invoke(
            app, ["predict", "--model", str(out), "--displacements", str(tmp_path / name)]
        )
        assert isinstance(r.exception, InvalidInputError), (name, repr(r.exception))
        assert name in str(r.exception)
