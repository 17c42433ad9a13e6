"""Element tangents: the contracted neo-Hookean form equals the generic 4th-order path."""

from __future__ import annotations

import numpy as np

from riskplan.deformable.assembly import element_tangents, neohookean_element_tangents
from riskplan.deformable.elements import determinants_and_inverses
from riskplan.deformable.laws import neohookean_energy_stress
from tests.conftest import TOL


def test_fast_neohookean_tangent_equals_generic(poly200, rng, tol):
    """Contracted neo-Hookean element matrices == generic 4th-order-tangent path."""
    F = np.eye(2) + 0.2 * rng.normal(size=(poly200.n_elements, 2, 2))
    F = F[np.linalg.det(F) > 0.1]
    G, ar = poly200.shape_gradients[: len(F)], poly200.areas[: len(F)]
    _, _, A = neohookean_energy_stress(F, 3.0, 1.7)
    J, Finv = determinants_and_inverses(F)
    fast = neohookean_element_tangents(Finv, np.log(J), G, ar, 3.0, 1.7)
    slow = np.einsum("t,tiJkL,taJ,tbL->taibk", ar, A, G, G).reshape(-1, 6, 6)
    np.testing.assert_allclose(
        fast,
        slow,
        rtol=TOL["float64_exact"]["rtol"],
        atol=TOL["float64_exact"]["atol"] * np.abs(slow).max(),
    )
    np.testing.assert_allclose(
        element_tangents(A, G, ar),
        slow,
        rtol=TOL["float64_exact"]["rtol"],
        atol=TOL["float64_exact"]["atol"] * np.abs(slow).max(),
    )
