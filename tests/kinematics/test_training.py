import math

import numpy as np
import pytest
import torch

from riskplan.errors import ConvergenceError, DataFormatError, InvalidInputError
from riskplan.kinematics import GaussianMixture
from riskplan.kinematics import training as training_mod
from riskplan.kinematics.data import read_point_clouds, write_synthetic_dataset
from riskplan.kinematics.training import CHECKPOINT_NAME, TrainConfig, train
from tests.conftest import TOL
from tests.kinematics.conftest import COV, FAST, make_synthetic, sample_true, true_mixture


def test_training_recovers_known_mixture(trained, rng):
    """Oracle: the data are drawn from a known, smoothly varying 2-component mixture."""
    res, _ = trained
    d = rng.uniform(0.0, 0.03, size=(20, 2))  # away from the edges of the sampled box
    gm = res.model.predict(d)
    w, mu, cov = true_mixture(d)
    # components identified by height (true means at z = 0.05 and z ~ 0.14)
    order = np.argsort(gm.means.numpy()[..., 2], axis=-1)
    take = lambda a: np.take_along_axis(a, order.reshape(order.shape + (1,) * (a.ndim - 2)), axis=1)  # noqa: E731
    w_hat, mu_hat, cov_hat = (
        take(gm.weights.numpy()),
        take(gm.means.numpy()),
        take(gm.covariances.numpy()),
    )
    np.testing.assert_allclose(w_hat, w, **TOL["recovered_weights"])
    np.testing.assert_allclose(mu_hat, mu, **TOL["recovered_means"])
    sd_hat = np.sqrt(np.diagonal(cov_hat, axis1=-2, axis2=-1))
    sd = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    np.testing.assert_allclose(sd_hat, np.broadcast_to(sd, sd_hat.shape), **TOL["recovered_sd"])
    corr = cov_hat[:, 1, 0, 1] / (sd_hat[:, 1, 0] * sd_hat[:, 1, 1])
    np.testing.assert_allclose(corr, 4.0 / 9.0, **TOL["recovered_correlation"])
    # and the fitted density is as good as the truth on fresh points (within 0.03 nats/point)
    x = sample_true(d, 2000, rng)
    true_gm = GaussianMixture.from_covariances(w, mu, np.broadcast_to(COV, (20, 2, 3, 3)).copy())
    gap = float(-gm.log_prob(x).mean() + true_gm.log_prob(x).mean())
    assert -0.02 < gap < 0.03


def test_training_history_and_outputs(trained):
    res, out = trained
    assert (
        (out / "weights.pt").is_file()
        and (out / "model.json").is_file()
        and (out / CHECKPOINT_NAME).is_file()
    )
    nll = [h.val_nll for h in res.history]
    assert all(math.isfinite(v) for v in nll)
    assert res.best_val_nll == min(nll)
    assert nll[-1] < nll[0] - 1.0  # it learned something
    assert res.skipped_steps == 0


def test_resume_continues_identically(synth_small, tmp_path):
    data = read_point_clouds(synth_small)
    cfg = TrainConfig(n_components=2, epochs=4, seed=3, **FAST)
    full = train(data, cfg, out=tmp_path / "full")
    cfg2 = TrainConfig(n_components=2, epochs=2, seed=3, **FAST)
    train(data, cfg2, out=tmp_path / "part")
    resumed = train(data, cfg, out=tmp_path / "part", resume=True)
    assert [h.epoch for h in resumed.history] == [0, 1, 2, 3]
    assert [h.val_nll for h in resumed.history] == [h.val_nll for h in full.history]
    a, b = full.model.net.state_dict(), resumed.model.net.state_dict()
    for k in a:
        assert torch.equal(a[k], b[k]), k
    ca = torch.load(tmp_path / "full" / CHECKPOINT_NAME, weights_only=True)
    cb = torch.load(tmp_path / "part" / CHECKPOINT_NAME, weights_only=True)
    for k in ca["net"]:
        assert torch.equal(ca["net"][k], cb["net"][k]), k


def test_training_is_the_seeded_adam_loop(synth_small, tmp_path):
    """Oracle for the loop's structure: three epochs of ``train`` give, bit for bit, the weights
    and training NLLs of the plain loop the module describes (shuffle and point draws from
    ``default_rng([seed, epoch])``, Adam on the mean NLL of the normalised points), so a
    restructuring of ``train`` that changes what it computes fails here."""
    from riskplan.kinematics.data import angle_columns
    from riskplan.kinematics.mdn import MDN, Normalisation, mixture_log_prob
    from riskplan.kinematics.training import split_indices

    data = read_point_clouds(synth_small)
    cfg = TrainConfig(n_components=2, epochs=3, seed=5, dtype="float64", lr_patience=10, **FAST)
    res = train(data, cfg, out=tmp_path)
    tr, _ = split_indices(data.n_configs, cfg.val_fraction, cfg.seed)
    angles = angle_columns(data.robot_toml)
    norm = Normalisation.fit(data.displacements[tr], data.points[tr], angles)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        net = MDN(data.n_tendons, 2, 3, cfg.hidden, cfg.head_hidden, cfg.activation, angles)
    net = net.double()
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    x_all = (data.displacements - norm.input_mean) / norm.input_scale
    for epoch in range(cfg.epochs):
        rng = np.random.default_rng([cfg.seed, epoch])
        perm = rng.permutation(tr)
        total = 0.0
        for s in range(0, perm.size, cfg.batch_size):
            idx = perm[s : s + cfg.batch_size]
            pidx = rng.integers(0, data.n_points, size=(idx.size, cfg.points_per_config))
            pts = (data.points[idx[:, None], pidx] - norm.output_centre) / norm.output_scale
            opt.zero_grad()
            x = torch.as_tensor(x_all[idx])
            loss = -mixture_log_prob(*net(x), torch.as_tensor(pts)).mean()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * idx.size
        assert res.history[epoch].train_nll == total / tr.size + norm.log_scale_sum
    last = torch.load(tmp_path / CHECKPOINT_NAME, weights_only=True)["net"]
    for k, v in net.state_dict().items():
        assert torch.equal(last[k], v), k


def test_nan_loss_skips_step_and_keeps_parameters(synth_small, monkeypatch):
    data = read_point_clouds(synth_small)
    real = training_mod.mdn_nll
    state = {"calls": 0, "snapshot": None, "unchanged": None}

    def faulty(net, x, p):
        state["calls"] += 1
        params = [q.detach().clone() for q in net.parameters()]
        if state["calls"] == 3:
            state["snapshot"] = params
            return real(net, x, p) * torch.tensor(float("nan"), dtype=x.dtype)
        if state["calls"] == 4:
            state["unchanged"] = all(torch.equal(a, b) for a, b in zip(params, state["snapshot"]))
        return real(net, x, p)

    monkeypatch.setattr(training_mod, "mdn_nll", faulty)
    res = train(
        data, TrainConfig(n_components=2, epochs=2, batch_size=4, hidden=(16,), head_hidden=())
    )
    assert (
        state["unchanged"] is True
    )  # the NaN step did not touch the parameters (nor Adam's state)
    assert res.skipped_steps == 1 and res.history[0].skipped_steps == 1
    assert all(bool(torch.isfinite(q).all()) for q in res.model.net.parameters())
    assert all(math.isfinite(h.val_nll) for h in res.history)


def test_persistent_nan_raises(synth_small, monkeypatch):
    data = read_point_clouds(synth_small)
    monkeypatch.setattr(
        training_mod, "mdn_nll", lambda net, x, p: net(x)[0].sum() * float("inf") * 0.0
    )
    with pytest.raises(ConvergenceError, match="non-finite"):
        train(data, TrainConfig(n_components=2, epochs=3, batch_size=2, max_bad_steps=5))


def test_float32_and_float64_training(synth_small):
    data = read_point_clouds(synth_small)
    r32 = train(data, TrainConfig(n_components=2, epochs=3, dtype="float32", **FAST))
    r64 = train(data, TrainConfig(n_components=2, epochs=3, dtype="float64", **FAST))
    assert next(r32.model.net.parameters()).dtype == torch.float32
    assert next(r64.model.net.parameters()).dtype == torch.float64
    # same seed, same data: the two precisions follow the same path closely
    np.testing.assert_allclose(
        r32.history[-1].val_nll, r64.history[-1].val_nll, **TOL["float32_training"]
    )


def test_empty_dataset_rejected(tmp_path):
    p = write_synthetic_dataset(tmp_path / "empty.h5", np.zeros((0, 2)), np.zeros((0, 1, 4, 3)))
    with pytest.raises(DataFormatError, match="empty"):
        read_point_clouds(p)
    import h5py

    p2 = make_synthetic(tmp_path / "notdone.h5", 4, seed=0, starts=1, points=8)
    with h5py.File(p2, "r+") as f:
        f["done"][...] = False
    with pytest.raises(DataFormatError, match="empty"):
        read_point_clouds(p2)


def test_single_config_rejected_before_training(tmp_path):
    p = make_synthetic(tmp_path / "one.h5", 1, seed=0, starts=1, points=8)
    with pytest.raises(DataFormatError, match="at least 2"):
        train(read_point_clouds(p), TrainConfig(epochs=1), out=tmp_path / "m")
    assert not (tmp_path / "m").exists()


def test_resume_with_other_data_rejected(synth_small, tmp_path):
    data = read_point_clouds(synth_small)
    train(data, TrainConfig(n_components=2, epochs=1, **FAST), out=tmp_path / "m")
    other = read_point_clouds(
        make_synthetic(tmp_path / "other.h5", 24, seed=99, starts=1, points=128)
    )
    with pytest.raises(DataFormatError, match="content hash"):
        train(other, TrainConfig(n_components=2, epochs=2, **FAST), out=tmp_path / "m", resume=True)
    foreign = read_point_clouds(
        make_synthetic(
            tmp_path / "foreign.h5", 24, seed=3, starts=1, points=128, toml='name = "other"\n'
        )
    )
    with pytest.raises(DataFormatError, match="differs"):
        train(
            foreign, TrainConfig(n_components=2, epochs=2, **FAST), out=tmp_path / "m", resume=True
        )
    with pytest.raises(DataFormatError, match="n_components"):
        train(data, TrainConfig(n_components=3, epochs=2, **FAST), out=tmp_path / "m", resume=True)
    with pytest.raises(DataFormatError, match="no such file"):
        train(
            data, TrainConfig(n_components=2, epochs=2, **FAST), out=tmp_path / "none", resume=True
        )


def test_corrupted_checkpoint_rejected(synth_small, tmp_path):
    data = read_point_clouds(synth_small)
    train(data, TrainConfig(n_components=2, epochs=1, **FAST), out=tmp_path / "m")
    ck = tmp_path / "m" / CHECKPOINT_NAME
    ck.write_bytes(ck.read_bytes()[:200])
    with pytest.raises(DataFormatError, match="corrupted"):
        train(data, TrainConfig(n_components=2, epochs=2, **FAST), out=tmp_path / "m", resume=True)


def test_config_validation():
    with pytest.raises(InvalidInputError, match="val_fraction"):
        TrainConfig(val_fraction=1.0).validate()
    with pytest.raises(InvalidInputError, match="lr"):
        TrainConfig(lr=-1).validate()
    with pytest.raises(InvalidInputError, match="dtype"):
        TrainConfig(dtype="float16").validate()


def test_rerun_without_resume_refused_and_unfinished_models_marked(synth_small, tmp_path, caplog):
    from riskplan.kinematics import load_model

    data = read_point_clouds(synth_small)
    cfg = TrainConfig(n_components=2, epochs=3, seed=3, **FAST)
    out = tmp_path / "m"

    def interrupt(rec):  # Ctrl-C after the first epoch
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(data, cfg, out=out, on_epoch=interrupt)
    # the interrupted run used to be discarded silently by a rerun without --resume
    with pytest.raises(InvalidInputError, match=r"checkpoint at epoch 1 of 3.*--resume"):
        train(data, cfg, out=out)
    with caplog.at_level("WARNING"):
        assert load_model(out).metadata["finished"] is False
    assert "unfinished" in caplog.text
    res = train(data, cfg, out=out, resume=True)
    assert len(res.history) == 3 and load_model(out).metadata["finished"] is True
    with pytest.raises(InvalidInputError, match="checkpoint at epoch 3 of 3"):
        train(data, cfg, out=out)
    assert (
        len(
            train(
                data, TrainConfig(n_components=2, epochs=1, seed=3, **FAST), out=out, overwrite=True
            ).history
        )
        == 1
    )
