"""Fixtures for the collision tests: small obstacle sets built from closed primitives."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from riskplan.collision import Environment


def box_mesh(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


def random_upper(rng, d, scale=1.0):
    """Random upper-triangular U with positive diagonal (precision Cholesky factor)."""
    u = np.triu(rng.normal(size=(d, d)) * 0.3)
    u[np.diag_indices(d)] = np.exp(rng.normal(size=d) * 0.3)
    return u / scale


@pytest.fixture(scope="module")
def boxes_env():
    return Environment.from_meshes(
        [
            box_mesh([1, -1, -1], [2, 1, 1]),
            box_mesh([-1.5, 0.5, -0.5], [-0.5, 1.5, 0.5]),
            box_mesh([-1, -3, -1], [1, -2, 1]),
        ],
        names=["a", "b", "c"],
    )
