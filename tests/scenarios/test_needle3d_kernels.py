"""The 3-D needle's compiled hot paths against the array code they replace: the pose-vector
step against ``needle_step``, the grid-cell location against the general search, the
steering rule's precomputed paths against stepping every candidate, and the step's
tissue response by element blocks against one direct solve."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.scenarios.base import SimParams
from riskplan.scenarios.bevel import _pose_vector_step, needle_step, se3_exp_batch
from riskplan.scenarios.needle3d import Needle3DScenario
from riskplan.scenarios.needle3d_space import needle3d_steer
from tests.conftest import TOL, approx_tol


def _rotation(gen) -> np.ndarray:
    Q, r = np.linalg.qr(gen.standard_normal((3, 3)))
    Q = Q * np.sign(np.diag(r))
    return Q if np.linalg.det(Q) > 0 else -Q


def test_pose_vector_step_equals_needle_step():
    gen = np.random.default_rng(0)
    for k in range(300):
        R, p = _rotation(gen), gen.random(3)
        v, om, rho = gen.uniform(0, 0.5), gen.uniform(-10, 10), gen.uniform(0, 1)
        if k % 3 == 0:  # the series branch (θ < 1e-4) and a straight step
            om, rho = (1e-6, 1e-7) if k % 2 else (0.0, 0.0)
        R1, p1 = needle_step(R, p, v, om, tau=0.1, kappa=2.0, rho=rho)
        out = _pose_vector_step(np.concatenate([p, R.T.ravel()]), v, om, 0.1, 2.0, rho)
        np.testing.assert_allclose(out, np.concatenate([p1, R1.T.ravel()]), **TOL["round_off"])


def _steer_by_stepping(x_from, x_to, bounds, n_steps, tau, kappa, duty):
    """The steering rule's grid, every candidate stepped from the start (the reference)."""
    R = x_from[3:12].reshape(3, 3).T
    lo, hi = bounds[:, 0], bounds[:, 1]
    vs = lo[0] + (hi[0] - lo[0]) * np.array([0.2, 0.4, 0.6, 0.8, 1.0])
    rhos = np.linspace(lo[2], hi[2], 5) if duty else np.array([1.0])
    V, W, P = (
        g.ravel() for g in np.meshgrid(vs, np.linspace(lo[1], hi[1], 41), rhos, indexing="ij")
    )
    xi = np.zeros((len(V), 6))
    xi[:, 2], xi[:, 3], xi[:, 5] = tau * V, tau * P * kappa * V, tau * W
    E, d = se3_exp_batch(xi)
    Rk, pk = np.broadcast_to(R, E.shape), np.broadcast_to(x_from[:3], d.shape)
    best = np.full(len(V), np.inf)
    for _ in range(n_steps):
        pk = pk + np.einsum("nij,nj->ni", Rk, d)
        Rk = Rk @ E
        best = np.minimum(best, np.linalg.norm(pk - x_to[:3], axis=1))
    return np.stack([V, W, P], axis=1)[:, : bounds.shape[0]], best


@pytest.mark.parametrize("duty", [False, True])
def test_steering_picks_the_nearest_approach_of_the_stepped_paths(duty):
    """The chosen control's nearest approach is the least of the stepped candidates' (up to
    round-off: candidates mirrored in ω can tie exactly)."""
    gen = np.random.default_rng(1)
    bounds = np.array([[0.0, 0.5], [-10.0, 10.0], [0.0, 1.0]])[: 3 if duty else 2]
    for _ in range(60):
        x = np.concatenate([gen.random(3), _rotation(gen).T.ravel()])
        t = np.concatenate([gen.random(3), np.zeros(9)])
        u = needle3d_steer(x, t, bounds, 6, tau=0.1, kappa=2.0, duty=duty)
        U, best = _steer_by_stepping(x, t, bounds, 6, 0.1, 2.0, duty)
        chosen = np.flatnonzero(np.all(U == u, axis=1))
        assert chosen.size == 1
        assert best[chosen[0]] == pytest.approx(best.min(), **approx_tol("float64_exact"))


def test_step_on_5k_tetrahedra_equals_the_direct_solve():
    """A needle step on the 5040-tetrahedra mesh: the world pose and the tracked points'
    displacement by element blocks against one solve of the whole system."""
    sim = Needle3DScenario()
    p = SimParams(youngs_modulus=47.0, poissons_ratio=0.41, n_elements=5000)
    model, block = sim.model(p), sim.mesh_data(5000).block
    y = sim.initial_state(p)
    for u in ([0.5, 10.0], [0.5, 0.0], [0.4, -3.0], [0.3, 2.0]):
        y = sim.step(y, u, p)
        e, lam = block.locate(y.material[:3])
        u_tip, tracked = model.point_load_direct(int(e[0]), lam[0], y.material[9:12])
        scale = float(np.abs(tracked).max())
        np.testing.assert_allclose(y.displacement / scale, tracked / scale, **TOL["float64_exact"])
        np.testing.assert_allclose(y.pose[:3], y.material[:3] + u_tip, **TOL["float64_exact"])


@pytest.mark.parametrize("n_elements", [1296, 5000])
def test_point_location_by_grid_cell_holds_the_point(n_elements):
    """``locate_point`` (the compiled cell lookup) returns a tetrahedron holding the point
    whose weights reproduce it, inside cells, on cell faces and corners, as the general
    search's does."""
    from riskplan.deformable.tetlocate import find_points

    block = Needle3DScenario().mesh_data(n_elements).block
    gen = np.random.default_rng(5)
    h = block.size / np.array(block.grid)
    pts = np.vstack([gen.random((60, 3)), h * gen.integers(0, 7, (20, 3)), [[1.0, 1.0, 1.0]]])
    for X in pts:
        e, lam = block.locate_point(X)
        e_ref, _ = find_points(block.mesh, X[None, :])
        assert e >= 0 and e_ref[0] >= 0
        assert lam.min() >= -TOL["barycentric"]["atol"]
        np.testing.assert_allclose(lam @ block.mesh.nodes[block.tets[e]], X, **TOL["interpolation"])


def test_point_location_refuses_points_outside_the_block():
    from riskplan.errors import InvalidInputError

    block = Needle3DScenario().mesh_data(1296).block
    for X in ([-0.01, 0.5, 0.5], [0.5, 1.01, 0.5], [0.5, 0.5, np.nan]):
        with pytest.raises(InvalidInputError, match="outside"):
            block.locate_point(np.array(X))
