"""The compiled neo-Hookean kernels against the array path they replace (same formulas,
other summation order: agreement to rounding), and the banded Cholesky against LAPACK."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from riskplan.deformable import Material, NeoHookeanModel, mesh_polygon, patch_load
from riskplan.deformable.nhkernels import (
    CompiledBandSolver,
    band_cholesky,
    band_cholesky_solve,
    scaled_norm,
)
from riskplan.errors import ElementInversionError
from tests.conftest import TOL


@pytest.fixture(scope="module")
def body():
    verts = np.array([[0.0, 0.0], [0.7, 0.0], [1.0, 0.3], [1.0, 1.0], [0.0, 1.0]])
    mesh = mesh_polygon(verts, 175)
    nb = mesh.nodes
    # the cut corner's edge is held (as in the manipulation scenario)
    fixed = np.flatnonzero(np.isclose(nb[:, 0] - nb[:, 1], 0.7, **TOL["float64_abs"]))
    f = patch_load(mesh, [0.0, 0.5], 0.15, [0.6, 0.2]) + patch_load(
        mesh, [0.5, 1.0], 0.15, [0.0, -0.5]
    )
    return mesh, Material(50.0, 0.4), fixed, f


def _pair(body):
    mesh, mat, fixed, _ = body
    fast = NeoHookeanModel(mesh, mat, fixed)
    slow = NeoHookeanModel(mesh, mat, fixed)
    slow.compiled = False
    assert fast.compiled
    return fast, slow


def _states(body, n=4):
    """Displacements along a loading path, up to a min det F of about 0.7."""
    mesh, mat, fixed, f = body
    ref = NeoHookeanModel(mesh, mat, fixed)
    ref.compiled = False
    return [ref.solve(s * f) for s in np.linspace(0.5, 2.0, n)]


def test_evaluate_matches_array_path(body):
    fast, slow = _pair(body)
    for u in _states(body):
        a = fast._evaluate(u.reshape(-1).copy())
        b = slow._evaluate(u.reshape(-1).copy())
        np.testing.assert_allclose(a.energy, b.energy, **TOL["float64_exact"])
        np.testing.assert_allclose(a.fint, b.fint, **TOL["float64_exact"])
        np.testing.assert_allclose(a.Finv, b.Finv, **TOL["float64_exact"])
        np.testing.assert_allclose(a.lnJ, b.lnJ, **TOL["float64_exact"])
        np.testing.assert_allclose(a.J, b.J, **TOL["float64_exact"])


def test_factorised_tangent_matches_array_path(body):
    # K⁻¹ r from the compiled band assembly + Cholesky against the array path's LAPACK solve,
    # and K (K⁻¹ r) = r with the tangent assembled independently (scipy sparse)
    fast, slow = _pair(body)
    rng = np.random.default_rng(0)
    for u in _states(body):
        a = fast._evaluate(u.reshape(-1).copy())
        b = slow._evaluate(u.reshape(-1).copy())
        r = rng.standard_normal(len(fast.free_dofs))
        x = fast._factor(a)(r)
        assert isinstance(fast._factor(a), CompiledBandSolver)
        np.testing.assert_allclose(x, slow._factor(b)(r), **TOL["float64_exact"])
        K = slow.tangent(u)
        np.testing.assert_allclose(K @ x, r, **TOL["float64_exact"])


def test_solves_match_array_path(body):
    f = body[3]
    fast, slow = _pair(body)
    u0 = None
    for s in (0.5, 1.0, 2.0):
        ua, ia = fast.solve_with_info(s * f, u0)
        ub, ib = slow.solve_with_info(s * f, u0)
        # both converge to rtol 1e-9 of the load: the same equilibrium to that tolerance
        np.testing.assert_allclose(ua, ub, **TOL["newton_paths"])
        assert ia.iterations == ib.iterations and ia.load_steps == ib.load_steps
        u0 = ua


def test_inverted_state_is_reported_by_both_paths(body):
    mesh = body[0]
    fast, slow = _pair(body)
    u = np.zeros((mesh.n_nodes, 2))
    u[mesh.triangles[0, 0]] = mesh.nodes[mesh.triangles[0, 1]] - mesh.nodes[mesh.triangles[0, 0]]
    u[mesh.triangles[0, 0]] *= 1.5  # node 0 of element 0 pushed past node 1: inverted
    for m in (fast, slow):
        with pytest.raises(ElementInversionError) as info:
            m.energy(u)
        assert 0 in info.value.elements
    a = fast._evaluate(u.reshape(-1).copy())
    b = slow._evaluate(u.reshape(-1).copy())
    assert a.energy is None and b.energy is None
    np.testing.assert_allclose(a.J, b.J, **TOL["float64_exact"])


def _random_band(n, kd, seed, shift):
    rng = np.random.default_rng(seed)
    K = np.zeros((n, n))
    for i in range(n):
        for j in range(i, min(n, i + kd + 1)):
            K[i, j] = K[j, i] = rng.standard_normal() * (rng.random() < 0.5)
    K += shift * np.eye(n)
    R = np.zeros((n, kd + 1))
    lapack = np.zeros((kd + 1, n))
    for j in range(n):
        for m in range(min(kd, n - 1 - j) + 1):
            R[j, m] = K[j, j + m]
            lapack[kd - m, j + m] = K[j, j + m]
    return K, R, lapack


@pytest.mark.parametrize("n, kd", [(1, 0), (7, 3), (60, 9), (40, 45)])
def test_band_cholesky_matches_lapack(n, kd):
    K, R, lapack = _random_band(n, kd, n + kd, shift=2.0 * kd + 2.0)
    assert band_cholesky(R) == 0
    U = scipy.linalg.cholesky_banded(lapack, lower=False)
    for j in range(n):
        for m in range(min(kd, n - 1 - j) + 1):
            np.testing.assert_allclose(R[j, m], U[kd - m, j + m], **TOL["float64_exact"])
    perm = np.random.default_rng(1).permutation(n)
    r = np.random.default_rng(2).standard_normal(n)
    x = band_cholesky_solve(R, perm, r)
    # the factor is of K[perm][:, perm]: x solves K' x' = r' with K' = P K Pᵀ
    Kp = np.empty_like(K)
    Kp[np.ix_(perm, perm)] = K
    np.testing.assert_allclose(Kp @ x, r, **TOL["float64_exact"])


def test_band_cholesky_reports_indefinite_like_lapack():
    K, R, lapack = _random_band(30, 4, 3, shift=0.0)
    K[10, 10] = R[10, 0] = lapack[4, 10] = -50.0
    info = band_cholesky(R)
    with pytest.raises(np.linalg.LinAlgError):
        scipy.linalg.cholesky_banded(lapack, lower=False)
    assert 1 <= info <= 11  # the first minor that is not positive definite, 1-based
    R2 = R.copy()
    R2[0, 0] = np.nan
    assert band_cholesky(R2) == 1


def test_scaled_norm():
    x = np.array([3.0, -4.0, 0.0])
    assert scaled_norm(x) == pytest.approx(5.0, **{"rel": TOL["float64_bits"]["rtol"]})
    assert scaled_norm(x * 1e300) == pytest.approx(5e300, rel=TOL["float64_exact"]["rtol"])
    assert scaled_norm(np.zeros(3)) == 0.0
    assert np.isnan(scaled_norm(np.array([1.0, np.nan])))
    assert scaled_norm(np.array([1.0, -np.inf])) == np.inf


def test_wide_band_uses_lapack_and_matches_array_path(body):
    # a finer mesh (bandwidth above LAPACK_BANDWIDTH): the compiled assembly in LAPACK's
    # storage, factorised by pbtrf, against the array path
    from riskplan.deformable.banded import BandedCholeskySolver
    from riskplan.deformable.nhkernels import LAPACK_BANDWIDTH

    _, mat, _, _ = body
    verts = np.array([[0.0, 0.0], [0.7, 0.0], [1.0, 0.3], [1.0, 1.0], [0.0, 1.0]])
    mesh = mesh_polygon(verts, 800)
    nb = mesh.nodes
    fixed = np.flatnonzero(np.isclose(nb[:, 0] - nb[:, 1], 0.7, **TOL["float64_abs"]))
    f = patch_load(mesh, [0.0, 0.5], 0.15, [0.6, 0.2])
    fast = NeoHookeanModel(mesh, mat, fixed)
    slow = NeoHookeanModel(mesh, mat, fixed)
    slow.compiled = False
    assert fast._pattern.bandwidth > LAPACK_BANDWIDTH
    ua = fast.solve(f)
    ub = slow.solve(f)
    np.testing.assert_allclose(ua, ub, **TOL["newton_paths"])
    st = fast._evaluate(ua.reshape(-1).copy())
    assert isinstance(fast._factor(st), BandedCholeskySolver)
    r = np.random.default_rng(3).standard_normal(len(fast.free_dofs))
    x = fast._factor(st)(r)  # 850 unknowns: round-off accumulates past float64_exact
    np.testing.assert_allclose(slow.tangent(ua) @ x, r, **TOL["float64_accumulated"])
