from __future__ import annotations

import numpy as np
import pytest

from riskplan.deformable import (
    LinearElasticModel,
    Material,
    body_load,
    element_stresses,
    mesh_polygon,
    rectangle,
    traction_load,
)
from riskplan.deformable.loads import subdivided_triangle_rule
from riskplan.errors import InvalidInputError
from tests.conftest import TOL


def _stress(mat, A):
    eps = 0.5 * (A + A.T)
    return mat.lam * np.trace(eps) * np.eye(2) + 2 * mat.mu * eps


@pytest.mark.parametrize("plane", ["stress", "strain"])
def test_patch_test_dirichlet(poly200, rng, plane, tol):
    """Linear field prescribed on the whole boundary is reproduced at interior nodes."""
    mat = Material(E=50.0, nu=0.4, plane=plane)
    bnd = poly200.boundary_nodes
    model = LinearElasticModel(poly200, mat, bnd)
    A, c = rng.normal(size=(2, 2)), rng.normal(size=2)
    exact = poly200.nodes @ A.T + c
    u = model.solve(np.zeros((poly200.n_nodes, 2)), fixed_values=exact[model.fixed_nodes])
    np.testing.assert_allclose(u, exact, **TOL["float64_abs"])
    np.testing.assert_allclose(
        element_stresses(poly200, mat, u),
        np.broadcast_to(_stress(mat, A), (poly200.n_elements, 2, 2)),
        **TOL["linear_fem"],
    )


def test_patch_test_traction(poly200, rng, tol):
    """Constant stress: consistent tractions σn on the boundary + two pinned nodes."""
    mat = Material(E=50.0, nu=0.3)
    A, c = rng.normal(size=(2, 2)), rng.normal(size=2)
    exact = poly200.nodes @ A.T + c
    sig = _stress(mat, A)
    f = traction_load(poly200, lambda x, n: n @ sig.T)
    pins = np.array([0, 2])
    model = LinearElasticModel(poly200, mat, pins)
    u = model.solve(f, fixed_values=exact[model.fixed_nodes])
    np.testing.assert_allclose(u, exact, **TOL["linear_fem"])
    np.testing.assert_allclose(model.residual(u, f), 0.0, **TOL["linear_fem"])


def _manufactured(lam, mu):
    pi = np.pi
    g = lambda t: t - t * t  # noqa: E731
    gp = lambda t: 1 - 2 * t  # noqa: E731

    def u(x):
        X, Y = x[..., 0], x[..., 1]
        return np.stack([np.sin(pi * X) * np.sin(pi * Y), g(X) * g(Y)], axis=-1)

    def grad(x):
        X, Y = x[..., 0], x[..., 1]
        return np.stack(
            [
                np.stack(
                    [pi * np.cos(pi * X) * np.sin(pi * Y), pi * np.sin(pi * X) * np.cos(pi * Y)], -1
                ),
                np.stack([gp(X) * g(Y), g(X) * gp(Y)], -1),
            ],
            -2,
        )

    def b(x):  # b = -div σ = -(μ Δu + (λ+μ) ∇ div u)
        X, Y = x[:, 0], x[:, 1]
        u1 = np.sin(pi * X) * np.sin(pi * Y)
        b1 = -(mu * (-2 * pi**2 * u1) + (lam + mu) * (-(pi**2) * u1 + gp(X) * gp(Y)))
        b2 = -(
            mu * (-2 * g(Y) - 2 * g(X))
            + (lam + mu) * (pi**2 * np.cos(pi * X) * np.cos(pi * Y) - 2 * g(X))
        )
        return np.stack([b1, b2], axis=1)

    return u, grad, b


def _errors(mesh, uh, u, grad):
    bary, w = subdivided_triangle_rule(2)
    p = mesh.nodes[mesh.triangles]
    x = np.einsum("qa,tad->tqd", bary, p)
    uq = np.einsum("qa,tad->tqd", bary, uh[mesh.triangles])
    gh = np.einsum("tai,taj->tij", uh[mesh.triangles], mesh.shape_gradients)
    l2 = np.sqrt(np.einsum("t,q,tqd->", mesh.areas, w, (uq - u(x)) ** 2))
    h1 = np.sqrt(np.einsum("t,q,tqij->", mesh.areas, w, (gh[:, None] - grad(x)) ** 2))
    return l2, h1


@pytest.mark.slow
def test_convergence_rates_manufactured_solution():
    """P1: ‖u − u_h‖_L2 = O(h²), |u − u_h|_H1 = O(h) for a smooth manufactured solution."""
    mat = Material(E=50.0, nu=0.3, plane="strain")
    u, grad, b = _manufactured(mat.lam, mat.mu)
    hs, l2s, h1s = [], [], []
    for n in (200, 800, 3200, 12800):
        mesh = mesh_polygon(rectangle(), n)
        model = LinearElasticModel(mesh, mat, mesh.boundary_nodes)
        uh = model.solve(body_load(mesh, b))
        l2, h1 = _errors(mesh, uh, u, grad)
        hs.append(np.sqrt(mesh.area / mesh.n_elements))
        l2s.append(l2)
        h1s.append(h1)
    rate_l2 = np.polyfit(np.log(hs), np.log(l2s), 1)[0]
    rate_h1 = np.polyfit(np.log(hs), np.log(h1s), 1)[0]
    assert 1.8 <= rate_l2 <= 2.3, (rate_l2, l2s)
    assert 0.85 <= rate_h1 <= 1.2, (rate_h1, h1s)


def test_dense_and_sparse_paths_agree(square175, rng, tol, monkeypatch):
    mat = Material(50.0, 0.4)
    f = rng.normal(size=(square175.n_nodes, 2))
    dense = LinearElasticModel(square175, mat, square175.vertex_nodes)
    import riskplan.deformable.linear as lin

    monkeypatch.setattr(lin, "DENSE_MAX_DOFS", 0)
    sparse = LinearElasticModel(square175, mat, square175.vertex_nodes)
    assert dense._inv is not None and sparse._lu_solve is not None
    F2 = rng.normal(size=(len(dense.free_dofs), 3))
    np.testing.assert_allclose(sparse.solve_free(F2), dense.solve_free(F2), **tol["float64_ref"])
    np.testing.assert_allclose(dense.solve(f), sparse.solve(f), **tol["float64_ref"])
    np.testing.assert_allclose(
        dense.solve_flat(f.ravel()), dense.solve(f).ravel(), **tol["float64_exact"]
    )
    np.testing.assert_allclose(dense.residual(dense.solve(f), f), 0.0, **TOL["linear_fem"])


def test_with_material_equals_fresh_assembly(square175, tol, rng):
    f = rng.normal(size=(square175.n_nodes, 2))
    a = LinearElasticModel(square175, Material(50.0, 0.4), square175.vertex_nodes)
    b = a.with_material(Material(30.0, 0.2, plane="strain"))
    c = LinearElasticModel(square175, Material(30.0, 0.2, plane="strain"), square175.vertex_nodes)
    np.testing.assert_allclose(b.solve(f), c.solve(f), **tol["float64_exact"])
    # linearity in 1/E
    d = a.with_material(Material(100.0, 0.4))
    np.testing.assert_allclose(d.solve(f), 0.5 * a.solve(f), **tol["float64_ref"])


def test_energy_and_reactions(square175, rng, tol):
    model = LinearElasticModel(square175, Material(50.0, 0.4), square175.vertex_nodes)
    f = rng.normal(size=(square175.n_nodes, 2))
    f[model.fixed_nodes] = 0.0
    u = model.solve(f)
    # Clapeyron: strain energy = ½ f·u; reactions balance the applied load
    np.testing.assert_allclose(model.energy(u), 0.5 * np.sum(f * u), **tol["float64_ref"])
    np.testing.assert_allclose(model.reactions(u).sum(0), -f.sum(0), **TOL["linear_fem"])


@pytest.mark.parametrize(
    "E, nu, plane",
    [
        (0.0, 0.3, "stress"),
        (-1.0, 0.3, "stress"),
        (1.0, 0.5, "stress"),
        (1.0, -1.0, "stress"),
        (np.nan, 0.3, "stress"),
        (1.0, 0.3, "3d"),
        ("a", 0.3, "stress"),
    ],
)
def test_material_validation(E, nu, plane):
    with pytest.raises(InvalidInputError):
        Material(E, nu, plane)


def test_material_lame_values(tol):
    m = Material(50.0, 0.4, "strain")
    np.testing.assert_allclose(m.mu, 50.0 / 2.8, **tol["float64_exact"])
    np.testing.assert_allclose(m.lam, 50.0 * 0.4 / (1.4 * 0.2), **tol["float64_exact"])
    s = Material(50.0, 0.4, "stress")
    np.testing.assert_allclose(s.lam, 2 * m.lam * m.mu / (m.lam + 2 * m.mu), **tol["float64_exact"])


def test_model_input_errors(square175):
    mat = Material(50.0, 0.4)
    with pytest.raises(InvalidInputError, match="fixed_nodes"):
        LinearElasticModel(square175, mat, [])
    with pytest.raises(InvalidInputError, match="fixed_nodes"):
        LinearElasticModel(square175, mat, [0])
    with pytest.raises(InvalidInputError, match="fixed_nodes"):
        LinearElasticModel(square175, mat, [0, 10_000])
    model = LinearElasticModel(square175, mat, square175.vertex_nodes)
    with pytest.raises(InvalidInputError, match="nodal_forces"):
        model.solve(np.zeros((3, 2)))
    bad = np.zeros((square175.n_nodes, 2))
    bad[5, 1] = np.nan
    with pytest.raises(InvalidInputError, match="NaN"):
        model.solve(bad)


@pytest.mark.parametrize("n", [175, 1000])
def test_models_pickle_round_trip(n, rng, tol):
    """Models travel to worker processes (riskplan.parallel): pickle gives the same solves."""
    import pickle

    from riskplan.deformable import NeoHookeanModel, locate

    mesh = mesh_polygon(rectangle(), n)
    mat = Material(50.0, 0.4)
    f = locate(mesh, [[0.4, 0.6]]).spread(np.array([[1.0, -0.5]]))
    for model in (
        LinearElasticModel(mesh, mat, mesh.vertex_nodes),
        NeoHookeanModel(mesh, mat, mesh.vertex_nodes),
    ):
        clone = pickle.loads(pickle.dumps(model))
        np.testing.assert_allclose(clone.solve(f), model.solve(f), **tol["float64_exact"])


def test_unsupported_part_is_reported():
    """Two separate squares, only one held: singular stiffness -> InvalidInputError."""
    from riskplan.deformable import TissueMesh

    nodes = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [2, 0], [3, 0], [3, 1], [2, 1]], dtype=float)
    tris = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    mesh = TissueMesh(nodes, tris)
    with pytest.raises(InvalidInputError, match="singular"):
        LinearElasticModel(mesh, Material(50.0, 0.4), [0, 1])
