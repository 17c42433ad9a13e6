"""Property-based tests of the data-set entry points (see tests/properties.py for the contract)."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from riskplan.datasets import get_protocol, load_dataset, storage
from riskplan.datasets.protocol import Protocol
from riskplan.robots import load_robot
from tests.properties import PROPERTY, any_float, assert_finite, call, junk

TOML = load_robot("paper").toml_text()


@PROPERTY
@given(
    changes=st.fixed_dictionaries(
        {},
        optional={
            k: st.one_of(st.integers(-3, 10), any_float, junk())
            for k in ("grid_levels", "n_starts", "n_points", "n_train", "surface_spacing")
        },
    )
)
def test_protocol_arbitrary(changes):
    base = get_protocol("tiny")
    p = call(base.replace, **changes)
    if p is not None:
        q = call(Protocol.from_json, p.to_json())
        assert q == p


@PROPERTY
@given(
    points=hnp.arrays(
        np.float32, (2, 1, 3, 3), elements=st.floats(width=32, allow_nan=True, allow_infinity=True)
    ),
    disp=hnp.arrays(np.float64, (2, 4), elements=any_float),
)
def test_load_dataset_arbitrary_arrays(tmp_path_factory, points, disp):
    p = tmp_path_factory.mktemp("h") / "d.h5"
    with storage.create_file(
        p,
        displacements=disp,
        n_starts=1,
        n_points=3,
        robot_toml=TOML,
        robot_name="paper",
        protocol_json=json.dumps({}),
        split="train",
        seed=0,
    ) as f:
        for i in range(2):
            storage.write_config(
                f, i, points[i], np.zeros((1, 3)), np.zeros((1, 4)), np.zeros((1, 4))
            )
        storage.mark_complete(f)
    ds = call(load_dataset, p)
    if ds is not None:
        assert_finite(ds.points, ds.displacements)
        assert np.all(np.linalg.norm(ds.points, axis=-1) <= storage.reach_bound(TOML))


@PROPERTY
@given(blob=st.binary(max_size=256))
def test_load_arbitrary_bytes(tmp_path_factory, blob):
    p = tmp_path_factory.mktemp("b") / "x.h5"
    p.write_bytes(blob)
    assert call(load_dataset, p) is None  # never a data set, always a named error
