"""Hyperelastic laws: stresses and tangents are the derivatives of the energies."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.deformable.laws import LAWS
from tests.conftest import TOL


def _random_F(rng, n=5):
    return np.eye(2) + 0.3 * rng.normal(size=(n, 2, 2))


@pytest.mark.parametrize("law", ["neohookean", "svk"])
def test_stress_and_tangent_are_derivatives(law, rng, tol):
    """P = ∂W/∂F and A = ∂P/∂F by central differences (float64)."""
    F = _random_F(rng)
    F = F[np.linalg.det(F) > 0.2]
    lam, mu = 3.0, 1.7
    _W, P, A = LAWS[law](F, lam, mu)
    h = 1e-6
    P_fd = np.zeros_like(P)
    A_fd = np.zeros_like(A)
    for k in range(2):
        for L in range(2):
            dF = np.zeros((2, 2))
            dF[k, L] = h
            Wp, Pp, _ = LAWS[law](F + dF, lam, mu, False)
            Wm, Pm, _ = LAWS[law](F - dF, lam, mu, False)
            P_fd[:, k, L] = (Wp - Wm) / (2 * h)
            A_fd[:, :, :, k, L] = (Pp - Pm) / (2 * h)
    np.testing.assert_allclose(P, P_fd, **TOL["fd_law"])
    np.testing.assert_allclose(A, A_fd, **TOL["fd_law"])
    # major symmetry A_iJkL = A_kLiJ (hyperelastic)
    np.testing.assert_allclose(A, np.einsum("tiJkL->tkLiJ", A), **tol["float64_exact"])
