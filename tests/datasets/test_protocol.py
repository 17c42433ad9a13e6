"""Protocol: preset counts, grid within limits, disjoint splits, straight paths."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.datasets.protocol import (
    PRESETS,
    Protocol,
    get_protocol,
    grid,
    random_starts,
    straight_path,
    target_configurations,
)
from riskplan.errors import InvalidInputError
from tests.conftest import TOL

LIMITS = np.array([[-0.01, 0.04]] * 4)


def test_paper_preset_counts_exactly_as_in_the_paper():
    p = PRESETS["paper"]
    tr = target_configurations(p, LIMITS, "train")
    te = target_configurations(p, LIMITS, "test")
    assert tr.shape == (2277, 4) and te.shape == (253, 4)
    assert p.n_configs("train") == 2277 and p.n_configs("test") == 253


@pytest.mark.parametrize("name", ["paper", "small", "tiny"])
def test_splits_disjoint_on_grid_within_limits(name):
    p = PRESETS[name]
    g = grid(LIMITS, p.grid_levels)
    tr = target_configurations(p, LIMITS, "train")
    te = target_configurations(p, LIMITS, "test")
    for x in (tr, te):
        assert np.all(x >= LIMITS[:, 0]) and np.all(x <= LIMITS[:, 1])
        # every target is a grid point
        assert np.all(np.isin(x.view([("", x.dtype)] * 4), g.view([("", g.dtype)] * 4)))
    assert len({tuple(r) for r in tr} & {tuple(r) for r in te}) == 0
    assert len({tuple(r) for r in tr}) == len(tr)
    # deterministic: depends on split_seed only
    np.testing.assert_array_equal(tr, target_configurations(p, LIMITS, "train"))
    assert not np.array_equal(
        tr, target_configurations(p.replace(split_seed=1), LIMITS, "train")
    ) or len(tr) == len(g)


def test_grid_levels_and_corners():
    g = grid(LIMITS, 3)
    assert g.shape == (81, 4)
    np.testing.assert_allclose(np.unique(g[:, 0]), [-0.01, 0.015, 0.04], **TOL["float64_exact"])
    np.testing.assert_allclose(g[0], LIMITS[:, 0], **TOL["float64_exact"])
    np.testing.assert_allclose(g[-1], LIMITS[:, 1], **TOL["float64_exact"])


def test_straight_path_and_random_starts(rng):
    starts = random_starts(LIMITS, 1000, rng)
    assert np.all(starts >= LIMITS[:, 0]) and np.all(starts <= LIMITS[:, 1])
    a, b = starts[0], starts[1]
    path = straight_path(a, b, 7)
    assert path.shape == (7, 4)
    np.testing.assert_array_equal(path[0], a)
    np.testing.assert_array_equal(path[-1], b)
    # equally spaced points on the segment
    np.testing.assert_allclose(
        np.diff(path, axis=0), np.broadcast_to((b - a) / 6, (6, 4)), **TOL["float64_ref"]
    )


def test_json_round_trip_and_bad_input():
    p = PRESETS["small"]
    assert Protocol.from_json(p.to_json()) == p
    assert get_protocol(p.to_json()) == p
    with pytest.raises(InvalidInputError, match="preset"):
        get_protocol("huge")
    with pytest.raises(InvalidInputError, match="unknown keys"):
        Protocol.from_json('{"bogus": 1}')
    with pytest.raises(InvalidInputError, match="n_starts"):
        Protocol(n_starts=0)
    with pytest.raises(InvalidInputError, match="exceeds"):
        target_configurations(Protocol(grid_levels=2, n_train=10, n_test=10), LIMITS, "train")
    with pytest.raises(InvalidInputError, match="split"):
        target_configurations(p, LIMITS, "validation")
