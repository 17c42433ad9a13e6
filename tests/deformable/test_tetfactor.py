"""The band of K⁻¹ by selected inversion (``tetfactor.band_inverse``) and the element blocks
of ``TetTissue.element_green_blocks`` against independent inverses: a dense inverse of a
random banded SPD matrix, of the reduced stiffness, and solves with unit forces."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from riskplan.deformable import Material, TetTissue, tet_block
from riskplan.deformable.tetfactor import band_inverse, element_band_index
from riskplan.errors import InvalidInputError
from tests.conftest import TOL


def _band(Z: np.ndarray, b: int) -> np.ndarray:
    """LAPACK's upper band layout of a dense symmetric matrix: ``out[b + i − j, j] = Z[i, j]``."""
    n = len(Z)
    out = np.zeros((b + 1, n))
    for j in range(n):
        for i in range(max(0, j - b), j + 1):
            out[b + i - j, j] = Z[i, j]
    return out


@pytest.mark.parametrize("n, b", [(1, 0), (7, 0), (9, 3), (40, 6), (25, 24)])
def test_band_inverse_equals_the_dense_inverse(n, b):
    gen = np.random.default_rng(n + b)
    A = np.zeros((n, n))
    for d in range(b + 1):  # a random SPD band matrix (diagonally dominant)
        v = gen.standard_normal(n - d)
        A += np.diag(v, d) + (np.diag(v, -d) if d else 0.0)
    A += np.diag(np.abs(A).sum(1) + 1.0)
    cb = scipy.linalg.cholesky_banded(_band(A, b), lower=False)
    zb = band_inverse(cb)
    np.testing.assert_allclose(zb, _band(np.linalg.inv(A), b), **TOL["float64_exact"])


@pytest.fixture(scope="module")
def tissue():
    mesh = tet_block((1.0, 1.0, 1.0), 750)
    return TetTissue(mesh, Material(61.3, 0.38), mesh.face_nodes("z-"))


def test_element_blocks_equal_the_dense_inverse(tissue):
    G = tissue.element_green_blocks()
    K = tissue.tangent(full=True).toarray()
    f = tissue.free_dofs
    Z = np.zeros_like(K)
    Z[np.ix_(f, f)] = np.linalg.inv(K[np.ix_(f, f)])
    ed = tissue._pattern.element_dofs
    ref = Z[ed[:, :, None], ed[:, None, :]]
    scale = float(np.abs(ref).max())
    np.testing.assert_allclose(G / scale, ref / scale, **TOL["float64_exact"])
    assert not G.flags.writeable and tissue.element_green_blocks() is G  # once per tissue
    # fixed DOFs answer zero: elements on the held face have zero rows and columns
    held = np.isin(tissue.mesh.tets, tissue.fixed_nodes)
    e, a = np.argwhere(held)[0]
    assert np.all(G[e, 3 * a : 3 * a + 3] == 0.0) and np.all(G[e, :, 3 * a : 3 * a + 3] == 0.0)


def test_element_blocks_equal_solves_on_5k_tetrahedra():
    mesh = tet_block((1.0, 1.0, 1.0), 5000)
    t = TetTissue(mesh, Material(50.0, 0.4), mesh.face_nodes("z-"))
    G = t.element_green_blocks()
    gen = np.random.default_rng(0)
    for e in gen.choice(mesh.n_elements, 8, replace=False):
        dofs = (3 * mesh.tets[e][:, None] + np.arange(3)).ravel()
        F = np.zeros((3 * mesh.n_nodes, 12))
        F[dofs, np.arange(12)] = 1.0
        U = np.zeros_like(F)
        U[t.free_dofs] = t.solve_linear_free(F[t.free_dofs])
        ref = U[dofs]
        scale = float(np.abs(ref).max())
        np.testing.assert_allclose(G[e] / scale, ref / scale, **TOL["float64_exact"])


def test_element_blocks_refuse_the_nonlinear_law_and_foreign_bands(tissue):
    nh = TetTissue(tissue.mesh, tissue.material, tissue.fixed_nodes, law="neo-hookean")
    with pytest.raises(InvalidInputError, match="linear"):
        nh.element_green_blocks()
    p = tissue._pattern
    with pytest.raises(InvalidInputError, match="band"):
        element_band_index(p.element_dofs, tissue.free_dofs, tissue.n_dofs, p.band_perm, 2)


def test_pickled_tissue_recomputes_the_same_blocks(tissue):
    import pickle

    G = tissue.element_green_blocks()
    t2 = pickle.loads(pickle.dumps(tissue))
    np.testing.assert_array_equal(t2.element_green_blocks(), G)
