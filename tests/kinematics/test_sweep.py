import json

import pytest

from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.kinematics import load_model
from riskplan.kinematics.sweep import parse_components, recommend, sweep
from riskplan.kinematics.training import TrainConfig
from tests.kinematics.conftest import FAST, make_synthetic


def test_parse_components():
    assert parse_components("1-4") == [1, 2, 3, 4]
    assert parse_components("5,1, 3") == [1, 3, 5]
    assert parse_components("2-3,7") == [2, 3, 7]
    for bad in ("", "0-3", "a", "4-2"):
        with pytest.raises(InvalidInputError):
            parse_components(bad)


def test_recommend_rule():
    ks = [1, 2, 3, 4, 5]
    nll = [-5.0, -6.0, -6.96, -7.0, -7.01]
    none = [[]] * 5
    assert recommend(ks, nll, none, 0.05) == 3  # -6.96 is within 0.05 of -7.01
    assert recommend(ks, nll, none, 0.0) == 5
    # K=3 collapsed: the next candidate
    assert recommend(ks, nll, [[], [], [2], [], []], 0.05) == 4
    # the best K collapsed: the best non-collapsed K within tolerance of the overall best, else the best non-collapsed
    assert recommend(ks, nll, [[], [], [1], [1], [0]], 0.05) == 2
    # a K whose training diverged (NaN) is never recommended
    assert recommend([1, 2, 3], [-5.0, float("nan"), -5.02], [[], [], []], 0.05) == 1
    assert recommend([1, 2], [float("nan"), -4.0], [[], []], 0.0) == 2
    with pytest.raises(InvalidInputError):
        recommend([], [], [], 0.05)
    with pytest.raises(InvalidInputError):
        recommend([1], [float("nan")], [[]], 0.05)


def test_sweep_small(synth_paths, tmp_path):
    cfg = TrainConfig(epochs=6, early_stop_patience=100, dtype="float64", **FAST)
    res = sweep(synth_paths[0], synth_paths[1], "1-2", cfg, out=tmp_path / "sw")
    assert res.components == [1, 2]
    # the data are a two-component mixture: K=2 fits better than one Gaussian
    assert res.test_nll[1] < res.test_nll[0] - 0.3
    assert res.recommended == 2
    for e in res.entries:
        assert len(e.weight_mean) == e.n_components
        assert load_model(e.model_path).n_components == e.n_components
    json.dumps(res.to_json())


def test_sweep_checks_data_before_training(synth_paths, tmp_path):
    foreign = make_synthetic(
        tmp_path / "foreign.h5", 8, seed=0, starts=1, points=8, toml='name = "x"\n'
    )
    with pytest.raises(DataFormatError, match="differs"):
        sweep(synth_paths[0], foreign, [1], TrainConfig(epochs=1), out=tmp_path / "sw")
    assert not (tmp_path / "sw").exists()


def test_sweep_uses_the_backend_it_is_given(synth_paths, tmp_path, monkeypatch):
    # reproduce passes its backend through (a serial or Ray run must not start local pools);
    # without one, workers > 1 means a local pool as before
    import riskplan.parallel as par

    seen = []
    real = par.map_tasks

    def spy(fn, items, **kw):
        seen.append((kw["backend"], kw["workers"]))
        return real(fn, items, **{**kw, "backend": "serial"})

    monkeypatch.setattr(par, "map_tasks", spy)
    cfg = TrainConfig(epochs=1, dtype="float64", **FAST)
    sweep(
        synth_paths[0], synth_paths[1], "1-2", cfg, out=tmp_path / "a", workers=2, backend="serial"
    )
    sweep(synth_paths[0], synth_paths[1], "1-2", cfg, out=tmp_path / "b", workers=2)
    sweep(synth_paths[0], synth_paths[1], "1-2", cfg, out=tmp_path / "c", workers=None)
    # workers=None is one per core, as everywhere: a pool wherever more than one core is free
    none_backend = "local" if par.effective_workers("local", None) > 1 else "serial"
    assert seen == [("serial", 2), ("local", 2), (none_backend, None)]
