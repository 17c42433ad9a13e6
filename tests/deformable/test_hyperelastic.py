from __future__ import annotations

import numpy as np
import pytest

from riskplan.deformable import (
    HyperelasticModel,
    LinearElasticModel,
    Material,
    NeoHookeanModel,
    locate,
    mesh_polygon,
    patch_load,
    rectangle,
)
from riskplan.deformable.laws import neohookean_energy_stress
from riskplan.errors import ConvergenceError, ElementInversionError, InvalidInputError
from tests.conftest import TOL


@pytest.mark.parametrize("law", ["neohookean", "svk"])
def test_assembled_tangent_equals_fd_of_residual(poly200, rng, law):
    mat = Material(50.0, 0.4, plane="strain")
    model = HyperelasticModel(poly200, mat, poly200.vertex_nodes[:2], law=law)
    u = 0.02 * rng.normal(size=(poly200.n_nodes, 2))
    u[model.fixed_nodes] = 0.0
    K = model.tangent(u, full=True).toarray()
    h = 1e-6
    cols = rng.choice(2 * poly200.n_nodes, 12, replace=False)
    for c in cols:
        du = np.zeros(2 * poly200.n_nodes)
        du[c] = h
        fp = model.internal_forces((u.ravel() + du).reshape(-1, 2)).ravel()
        fm = model.internal_forces((u.ravel() - du).reshape(-1, 2)).ravel()
        np.testing.assert_allclose(
            K[:, c],
            (fp - fm) / (2 * h),
            rtol=TOL["fd_tangent"]["rtol"],
            atol=TOL["fd_tangent"]["atol"] * np.abs(K).max(),
        )
    # internal forces are the gradient of the stored energy
    g = np.array(
        [
            (
                model.energy((u.ravel() + h * e).reshape(-1, 2))
                - model.energy((u.ravel() - h * e).reshape(-1, 2))
            )
            / (2 * h)
            for e in np.eye(2 * poly200.n_nodes)[cols]
        ]
    )
    np.testing.assert_allclose(g, model.internal_forces(u).ravel()[cols], **TOL["fd_jacobian"])
    # reduced tangent is the free-free block of the full one
    Kr = model.tangent(u).toarray()
    np.testing.assert_allclose(
        Kr, K[np.ix_(model.free_dofs, model.free_dofs)], **TOL["float64_exact"]
    )


@pytest.mark.parametrize("plane", ["stress", "strain"])
def test_tangent_at_rest_is_linear_stiffness(square175, plane, tol):
    """Independent assembly paths: scikit-fem linear K vs our vectorised tangent at u = 0."""
    mat = Material(50.0, 0.4, plane=plane)
    lin = LinearElasticModel(square175, mat, square175.vertex_nodes)
    nh = NeoHookeanModel(square175, mat, square175.vertex_nodes)
    K0 = nh.tangent(np.zeros((square175.n_nodes, 2)), full=True)
    np.testing.assert_allclose(
        K0.toarray(),
        lin.K.toarray(),
        rtol=TOL["float64_abs"]["rtol"],
        atol=TOL["float64_abs"]["atol"] * abs(lin.K).max(),
    )


@pytest.fixture(scope="module")
def manip():
    verts = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    mesh = mesh_polygon(verts, 175)
    be = mesh.boundary_edges
    # fixed: the bottom-right part of the boundary (x >= 0.6 on y = 0, and y <= 0.4 on x = 1)
    nb = mesh.nodes
    fixed = np.flatnonzero(
        ((nb[:, 1] == 0.0) & (nb[:, 0] >= 0.6)) | ((nb[:, 0] == 1.0) & (nb[:, 1] <= 0.4))
    )
    mat = Material(50.0, 0.4)
    # moderate load: min det F ~ 0.95 (ten times it gives min det F ~ 0.2)
    f = 0.1 * (
        patch_load(mesh, [0.0, 0.5], 0.15, [4.0, 1.0])
        + patch_load(mesh, [0.5, 1.0], 0.15, [0.0, -3.0])
    )
    assert len(be) > 0
    return mesh, mat, fixed, f


def test_small_loads_nonlinear_matches_linear(manip):
    mesh, mat, fixed, f = manip
    lin = LinearElasticModel(mesh, mat, fixed)
    nh = NeoHookeanModel(mesh, mat, fixed)
    diffs = []
    for s in (1e-3, 1e-2, 1e-1):
        ul, un = lin.solve(s * f), nh.solve(s * f)
        diffs.append(np.linalg.norm(un - ul) / np.linalg.norm(ul))
    diffs = np.array(diffs)
    # the relative difference is O(load): ~10x per decade, and small at small loads
    assert diffs[0] < TOL["small_load_linear"]["rtol"], diffs
    np.testing.assert_allclose(diffs[1:] / diffs[:-1], 10.0, **TOL["convergence_ratio"])


@pytest.mark.parametrize("law", ["neohookean", "svk"])
def test_equilibrium_after_solve_and_warm_start(manip, law):
    mesh, mat, fixed, f = manip
    nh = HyperelasticModel(mesh, mat, fixed, law=law)
    u, info = nh.solve_with_info(f)
    r = nh.residual(u, f)
    assert np.linalg.norm(r) <= nh.rtol * np.linalg.norm(f) + nh.atol
    np.testing.assert_allclose(
        info.residual,
        np.linalg.norm(r[~np.isin(np.arange(mesh.n_nodes), fixed)]),
        **TOL["residual_norm"],
    )
    assert info.min_jacobian > 0
    # a slightly different load: warm start needs fewer Newton iterations than a cold one
    f2 = 1.02 * f
    cold = nh.solve_with_info(f2)[1]
    u2, warm = nh.solve_with_info(f2, u0=u)
    assert warm.iterations < cold.iterations
    assert np.linalg.norm(nh.residual(u2, f2)) <= nh.rtol * np.linalg.norm(f2) + nh.atol
    # same equilibrium from either start
    np.testing.assert_allclose(u2, nh.solve(f2), **TOL["newton_paths"])


def test_large_deformation_and_load_steps(manip):
    mesh, mat, fixed, f = manip
    nh = NeoHookeanModel(mesh, mat, fixed)
    u1, i1 = nh.solve_with_info(8 * f)
    u4, i4 = nh.solve_with_info(8 * f, load_steps=4)
    assert i4.load_steps == 4
    np.testing.assert_allclose(u1, u4, **TOL["newton_paths"])
    assert i1.min_jacobian < 0.9  # genuinely nonlinear regime
    lin = LinearElasticModel(mesh, mat, fixed).solve(8 * f)
    assert np.linalg.norm(u1 - lin) / np.linalg.norm(lin) > 0.02


def test_deterministic(manip):
    mesh, mat, fixed, f = manip
    a = NeoHookeanModel(mesh, mat, fixed).solve(2 * f)
    b = NeoHookeanModel(mesh, mat, fixed).solve(2 * f)
    assert np.array_equal(a, b)


def test_start_cache_changes_no_result(manip):
    # restarts from the same displacement reuse its evaluation and factorisation: the
    # results are those of a fresh model, bit for bit, and the caller's arrays are not the
    # cached ones
    mesh, mat, fixed, f = manip
    warm = NeoHookeanModel(mesh, mat, fixed)
    u0 = warm.solve(f)
    loads = [f, 1.01 * f, 0.98 * f, 1.01 * f]
    outs = [warm.solve_with_info(g, u0) for g in loads]
    for g, (u, info) in zip(loads, outs):
        fresh_u, fresh_info = NeoHookeanModel(mesh, mat, fixed).solve_with_info(g, u0)
        assert np.array_equal(u, fresh_u) and info == fresh_info
    assert outs[0][1].iterations == 0  # already in equilibrium: the start itself
    outs[0][0][:] = 1e3  # the caller owns what it got back
    assert np.array_equal(warm.solve(f, u0), NeoHookeanModel(mesh, mat, fixed).solve(f, u0))


def test_point_load_inverts_then_raises(manip):
    """A huge point load cannot be carried without inversion: ElementInversionError or
    ConvergenceError, never a NaN state."""
    mesh, mat, fixed, _ = manip
    nh = NeoHookeanModel(mesh, mat, fixed, max_iter=8)
    f = locate(mesh, [[0.3, 0.6]]).spread(np.array([[0.0, -100.0]]))
    with pytest.raises((ElementInversionError, ConvergenceError)) as exc:
        nh.solve(f, load_steps=1)
    if isinstance(exc.value, ElementInversionError):
        assert len(exc.value.elements) > 0 and exc.value.min_jacobian <= 0
    else:
        assert exc.value.residual is not None and np.isfinite(exc.value.residual)


def test_inverted_warm_start_is_rejected(manip):
    mesh, mat, fixed, f = manip
    nh = NeoHookeanModel(mesh, mat, fixed)
    u0 = np.zeros((mesh.n_nodes, 2))
    free = np.setdiff1d(np.arange(mesh.n_nodes), fixed)
    u0[free] = -2.0 * mesh.nodes[free]  # mirrors the body through the origin: det F < 0
    with pytest.raises(ElementInversionError) as exc:
        nh.solve(f, u0=u0)
    assert exc.value.min_jacobian <= 0
    with pytest.raises(ElementInversionError):
        nh.energy(u0)


def test_convergence_error_carries_residual(manip):
    mesh, mat, fixed, f = manip
    nh = NeoHookeanModel(mesh, mat, fixed, max_iter=1)
    with pytest.raises(ConvergenceError) as exc:
        nh.solve_with_info(8 * f, max_halvings=0)
    assert exc.value.residual > 0


def test_bad_input(manip):
    mesh, mat, fixed, f = manip
    with pytest.raises(InvalidInputError, match="law"):
        HyperelasticModel(mesh, mat, fixed, law="mooney")
    nh = NeoHookeanModel(mesh, mat, fixed)
    with pytest.raises(InvalidInputError, match="load_steps"):
        nh.solve(f, load_steps=0)
    with pytest.raises(InvalidInputError, match="u0"):
        nh.solve(f, u0=np.zeros((3, 2)))
    with pytest.raises(InvalidInputError, match="nodal_forces"):
        nh.solve(np.full_like(f, np.nan))


def test_banded_solver_equals_sparse_lu(manip, rng, tol):
    from scipy.sparse.linalg import spsolve

    mesh, mat, fixed, f = manip
    nh = NeoHookeanModel(mesh, mat, fixed)
    u = nh.solve(5 * f)
    st = nh._evaluate(u.ravel().copy())
    r = rng.normal(size=len(nh.free_dofs))
    np.testing.assert_allclose(nh._factor(st)(r), spsolve(nh.tangent(u), r), **tol["float64_ref"])


@pytest.mark.parametrize("law", ["neohookean", "svk"])
def test_nonlinear_patch_test_homogeneous_deformation(poly200, rng, law):
    """A homogeneous deformation prescribed on the boundary is an exact discrete
    equilibrium (constant P): interior nodes must reproduce u = (F − I) X + c."""
    F = np.array([[1.3, 0.2], [-0.1, 0.85]])
    c = np.array([0.05, -0.02])
    exact = poly200.nodes @ (F - np.eye(2)).T + c
    model = HyperelasticModel(
        poly200, Material(50.0, 0.4, plane="strain"), poly200.boundary_nodes, law=law
    )
    u, _info = model.solve_with_info(
        np.zeros((poly200.n_nodes, 2)), fixed_values=exact[model.fixed_nodes], load_steps=2
    )
    np.testing.assert_allclose(u, exact, **TOL["linear_fem"])
    np.testing.assert_allclose(model.jacobians(u), np.linalg.det(F), **TOL["float64_exact_rel"])


def test_traction_patch_test_nonlinear(poly200):
    """Constant first Piola stress P(F) applied as the dead traction P N on the reference
    boundary, origin-free pins at two nodes with the exact values: u = (F − I) X."""
    from riskplan.deformable import traction_load

    F = np.array([[1.15, 0.1], [0.05, 0.9]])
    mat = Material(50.0, 0.4, plane="strain")
    _, P, _ = neohookean_energy_stress(F[None], mat.lam, mat.mu, False)
    f = traction_load(poly200, lambda x, n: n @ P[0].T)
    exact = poly200.nodes @ (F - np.eye(2)).T
    model = NeoHookeanModel(poly200, mat, [0, 2])
    u = model.solve(f, fixed_values=exact[model.fixed_nodes], load_steps=2)
    np.testing.assert_allclose(u, exact, **TOL["nonlinear_patch"])


@pytest.mark.slow
def test_neohookean_convergence_rate_manufactured():
    """Large-strain manufactured solution u* (max |∇u*| ≈ 0.6): body force b = −Div P(I + ∇u*)
    (divergence by central differences of the exact stress field, error ~1e-9), all
    boundary nodes fixed. P1 → ‖u − u_h‖_L2 = O(h²)."""
    from riskplan.deformable import body_load

    mat = Material(50.0, 0.3, plane="strain")
    amp = 0.2
    pi = np.pi

    def u_exact(x):
        X, Y = x[..., 0], x[..., 1]
        return amp * np.stack(
            [np.sin(pi * X) * np.sin(pi * Y), 4 * X * (1 - X) * Y * (1 - Y)], axis=-1
        )

    def grad_exact(x):
        X, Y = x[..., 0], x[..., 1]
        g = lambda t: t * (1 - t)  # noqa: E731
        gp = lambda t: 1 - 2 * t  # noqa: E731
        row0 = np.stack(
            [pi * np.cos(pi * X) * np.sin(pi * Y), pi * np.sin(pi * X) * np.cos(pi * Y)], -1
        )
        row1 = 4 * np.stack([gp(X) * g(Y), g(X) * gp(Y)], -1)
        return amp * np.stack([row0, row1], -2)

    def P_exact(x):
        F = np.eye(2) + grad_exact(x)
        return neohookean_energy_stress(F.reshape(-1, 2, 2), mat.lam, mat.mu, False)[1]

    def body(x):
        h = 1e-5
        div = np.zeros((len(x), 2))
        for J in range(2):
            e = np.zeros(2)
            e[J] = h
            div += (P_exact(x + e)[:, :, J] - P_exact(x - e)[:, :, J]) / (2 * h)
        return -div

    from riskplan.deformable.loads import subdivided_triangle_rule

    hs, errs = [], []
    for n in (200, 800, 3200):
        mesh = mesh_polygon(rectangle(), n)
        model = NeoHookeanModel(mesh, mat, mesh.boundary_nodes)
        uh = model.solve(body_load(mesh, body), load_steps=2)
        bary, w = subdivided_triangle_rule(2)
        x = np.einsum("qa,tad->tqd", bary, mesh.nodes[mesh.triangles])
        uq = np.einsum("qa,tad->tqd", bary, uh[mesh.triangles])
        errs.append(np.sqrt(np.einsum("t,q,tqd->", mesh.areas, w, (uq - u_exact(x)) ** 2)))
        hs.append(np.sqrt(mesh.area / n))
    rate = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert 1.8 <= rate <= 2.3, (rate, errs)


@pytest.mark.parametrize("scale", [1e10, 1e100, 1e200, 1e300])
def test_huge_loads_raise_named_errors(manip, scale):
    """Finite loads whose norm (or residual) overflows never come back as u = 0 with an
    infinite residual: a named error, at every scale."""
    mesh, mat, fixed, f = manip
    nh = NeoHookeanModel(mesh, mat, fixed, max_iter=8)
    with pytest.raises((ConvergenceError, ElementInversionError, InvalidInputError)):
        nh.solve_with_info(f / np.abs(f).max() * scale, max_halvings=1)


def test_tolerance_that_accepts_any_start_is_rejected(manip):
    mesh, mat, fixed, _ = manip
    for kw in (dict(rtol=1.0), dict(rtol=0.0), dict(atol=np.inf), dict(max_iter=0)):
        with pytest.raises(InvalidInputError, match="rtol"):
            NeoHookeanModel(mesh, mat, fixed, **kw)


def test_linear_solve_overflow_raises(manip):
    mesh, _, fixed, f = manip
    lin = LinearElasticModel(mesh, Material(1e-300, 0.4), fixed)
    with pytest.raises(ConvergenceError, match="overflows"):
        lin.solve(f * 1e10)


def test_load_steps_over_the_time_budget_refused_up_front(manip):
    from riskplan.errors import BudgetError

    mesh, mat, fixed, f = manip
    with pytest.raises(BudgetError, match="load_steps"):
        NeoHookeanModel(mesh, mat, fixed).solve(f, load_steps=10**9)
