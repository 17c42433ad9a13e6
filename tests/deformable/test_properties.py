"""Property-based tests of the deformable-tissue entry points (see tests/properties.py for the contract)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from riskplan.deformable import LinearElasticModel, Material, mesh_polygon, point_load, rectangle
from tests.conftest import TOL
from tests.properties import PROPERTY, any_float, arrays_or_junk, assert_finite, call, junk

MESH = mesh_polygon(rectangle(), 40)
MODEL = LinearElasticModel(
    MESH, Material(50.0, 0.4), np.flatnonzero(MESH.nodes[:, 1] < TOL["on_surface"]["atol"])
)


@PROPERTY
@given(
    E=st.one_of(any_float, junk(), st.integers()),
    nu=st.one_of(any_float, junk()),
    plane=st.one_of(st.sampled_from(["stress", "strain"]), junk()),
)
def test_material_arbitrary(E, nu, plane):
    m = call(Material, E, nu, plane)
    if m is not None:
        assert_finite(m.E, m.nu, m.mu, m.lam)
        assert m.mu > 0


@PROPERTY
@given(
    points=arrays_or_junk(
        hnp.array_shapes(min_dims=1, max_dims=2, min_side=1, max_side=3), st.floats(-0.5, 1.5)
    ),
    forces=arrays_or_junk(
        hnp.array_shapes(min_dims=1, max_dims=2, min_side=1, max_side=3), st.floats(-1e6, 1e6)
    ),
)
def test_point_loads_and_solve_arbitrary(points, forces):
    f = call(point_load, MESH, points, forces)
    if f is None:
        return
    assert_finite(f)
    u = call(MODEL.solve, f)
    if u is not None:
        assert_finite(u)
