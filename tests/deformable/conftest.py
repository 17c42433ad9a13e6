"""Fixtures for the FEM tests: small meshes of the two scenario shapes."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.deformable import mesh_polygon, rectangle

#: an L-shaped-ish non-convex polygon (exercises boundary handling and meshing)
POLY = np.array(
    [[0.0, 0.0], [1.2, 0.0], [1.2, 0.3], [1.0, 0.8], [0.5, 1.0], [0.5, 0.5], [0.0, 0.7]]
)


@pytest.fixture(scope="module")
def square175():
    return mesh_polygon(rectangle(), 175)


@pytest.fixture(scope="module")
def poly200():
    return mesh_polygon(POLY, 200)


@pytest.fixture(scope="module")
def poly_vertices():
    return POLY.copy()
