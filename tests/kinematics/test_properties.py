"""Property-based tests of the kinematics entry points (see tests/properties.py for the contract)."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from riskplan.kinematics import GaussianMixture
from riskplan.kinematics.training import TrainConfig
from tests.properties import PROPERTY, any_float, arrays_or_junk, assert_finite, call, junk

GM = GaussianMixture(
    np.array([[0.3, 0.7]]),
    np.zeros((1, 2, 3)),
    np.broadcast_to(np.eye(3) * 50.0, (1, 2, 3, 3)).copy(),
)


def _no_nan(t) -> None:
    a = t.detach().numpy() if isinstance(t, torch.Tensor) else np.asarray(t)
    assert not np.any(np.isnan(a)) and not np.any(a == np.inf), a


@PROPERTY
@given(points=arrays_or_junk(hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=3)))
def test_log_prob_arbitrary_points(points):
    lp = call(GM.log_prob, points)
    if lp is not None:
        _no_nan(lp)  # a log density: finite or -inf (density 0), never NaN or +inf


@PROPERTY
@given(w=arrays_or_junk(), m=arrays_or_junk(), u=arrays_or_junk(), x=arrays_or_junk())
def test_arbitrary_mixtures(w, m, u, x):
    gm = call(GaussianMixture, w, m, u)
    if gm is None:
        return
    assert_finite(gm.weights.numpy(), gm.means.numpy(), gm.precision_cholesky.numpy())
    lp = call(gm.log_prob, x)
    if lp is not None:
        _no_nan(lp)
    s = call(gm.sample, 3, seed=0)
    if s is not None:
        assert not torch.isnan(s).any()


@PROPERTY
@given(
    values=st.fixed_dictionaries(
        {},
        optional={
            k: st.one_of(st.integers(-5, 5), any_float, junk())
            for k in (
                "n_components",
                "epochs",
                "lr",
                "seed",
                "val_fraction",
                "early_stop_patience",
                "dtype",
            )
        },
    )
)
def test_train_config_validation(values):
    cfg = call(TrainConfig, **values)
    if cfg is not None:
        call(cfg.validate)
