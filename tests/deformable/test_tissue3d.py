"""3-D tetrahedral tissue: assembly against scikit-fem, patch test, neo-Hookean against the
homogeneous uniaxial-stress closed form, point location, snapshot/restore, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.deformable import Material, TetMesh, TetTissue, tet_block
from riskplan.errors import ConvergenceError, InvalidInputError
from tests.conftest import TOL

skfem = pytest.importorskip("skfem")

MAT = Material(10.0, 0.3)


@pytest.fixture(scope="module")
def block():
    return tet_block((1.0, 1.0, 2.0), n_elements=600)


def _rollers(m: TetMesh) -> np.ndarray:
    """Symmetry planes x = 0, y = 0, z = 0 (normal component held)."""
    return np.concatenate(
        [3 * m.face_nodes("x-"), 3 * m.face_nodes("y-") + 1, 3 * m.face_nodes("z-") + 2]
    )


def _face_load(m: TetMesh, face: str, traction) -> np.ndarray:
    """Consistent nodal forces of a uniform traction ``(3,)`` per reference area on a face."""
    nodes = m.face_nodes(face)
    tri = m.boundary_faces[np.all(np.isin(m.boundary_faces, nodes), axis=1)]
    p = m.nodes[tri]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    f = np.zeros((m.n_nodes, 3))
    for k in range(3):
        np.add.at(f[:, k], tri.ravel(), np.repeat(area / 3.0, 3) * traction[k])
    return f


def test_block_count_and_faces(block):
    assert block.n_elements == 600
    np.testing.assert_allclose(block.volume, 2.0, **TOL["float64_exact"])
    for face in ("x-", "x+", "y-", "y+", "z-", "z+"):
        assert block.face_nodes(face).size > 0
    m = tet_block(n_elements=5000)
    assert abs(m.n_elements - 5000) <= 0.05 * 5000


def test_linear_stiffness_equals_scikit_fem(block):
    from skfem.models.elasticity import linear_elasticity

    basis = skfem.Basis(block.to_skfem(), skfem.ElementVector(skfem.ElementTetP1()), intorder=1)
    K_ref = skfem.asm(linear_elasticity(MAT.lam3d, MAT.mu), basis).toarray()
    K = TetTissue(block, MAT, block.face_nodes("z-")).tangent(full=True).toarray()
    np.testing.assert_allclose(
        K, K_ref, rtol=0, atol=TOL["float64_exact"]["atol"] * abs(K_ref).max()
    )


def test_patch_uniaxial_tension_is_exact(block):
    """Uniaxial stress σ_zz = s: u = (−ν s/E x, −ν s/E y, s/E z) is linear, so P1 tets
    reproduce it exactly from the traction s on z = 2 with symmetry rollers."""
    s = 0.7
    t = TetTissue(block, MAT, fixed_dofs=_rollers(block))
    u = t.solve(_face_load(block, "z+", (0.0, 0.0, s)))
    X = block.nodes
    eps = s / MAT.E
    exact = np.stack([-MAT.nu * eps * X[:, 0], -MAT.nu * eps * X[:, 1], eps * X[:, 2]], 1)
    np.testing.assert_allclose(u, exact, **TOL["linear_fem"])


def _uniaxial_stretch(P33: float, lam: float, mu: float):
    """Exact (a, b) of F = diag(b, b, a) under nominal stress P33 with P11 = P22 = 0 for
    W = μ/2 (I₁ − 3 − 2 ln J) + λ/2 (ln J)²: P_ii = μ (F_ii − 1/F_ii) + λ ln J / F_ii."""
    from scipy.optimize import brentq

    def p(a, b):
        lnJ = np.log(a * b * b)
        return mu * (a - 1 / a) + lam * lnJ / a, mu * (b - 1 / b) + lam * lnJ / b

    def b_of(a):
        return brentq(lambda b: p(a, b)[1], 0.2, 2.0)

    a = brentq(lambda a: p(a, b_of(a))[0] - P33, 0.5, 4.0)
    return a, b_of(a)


@pytest.mark.parametrize("P33", [2.0, -1.5])
def test_neohookean_homogeneous_uniaxial_stress(P33):
    m = tet_block(n_elements=750)
    t = TetTissue(m, MAT, fixed_dofs=_rollers(m), law="neo-hookean")
    u, info = t.solve_with_info(_face_load(m, "z+", (0.0, 0.0, P33)), load_steps=2)
    a, b = _uniaxial_stretch(P33, MAT.lam3d, MAT.mu)
    X = m.nodes
    exact = np.stack([(b - 1) * X[:, 0], (b - 1) * X[:, 1], (a - 1) * X[:, 2]], 1)
    np.testing.assert_allclose(u, exact, **TOL["nonlinear_patch"])
    F = t.deformation_gradient_at([[0.3, 0.4, 0.5]])[0]
    np.testing.assert_allclose(F, np.diag([b, b, a]), **TOL["nonlinear_patch"])
    assert info.iterations >= 2


def test_neohookean_small_load_matches_linear(block):
    fixed = block.face_nodes("z-")
    f = _face_load(block, "z+", (1e-4, 0.0, 0.0))
    ul = TetTissue(block, MAT, fixed).solve(f)
    un = TetTissue(block, MAT, fixed, law="neo-hookean").solve(f)
    np.testing.assert_allclose(
        un, ul, rtol=0, atol=TOL["small_load_linear"]["rtol"] * abs(ul).max()
    )


def test_locate_and_interpolate(block):
    t = TetTissue(block, MAT, block.face_nodes("z-"))
    rng = np.random.default_rng(0)
    pts = rng.uniform([0, 0, 0], [1, 1, 2], size=(50, 3))
    elem, lam = t.locate(np.vstack([pts, [[2.0, 0.5, 0.5]]]))
    assert np.all(elem[:50] >= 0) and elem[50] == -1
    assert np.all(lam[:50] >= -TOL["barycentric"]["atol"])
    np.testing.assert_allclose(lam[:50].sum(1), 1.0, **TOL["float64_exact"])
    # an affine field is interpolated exactly
    A = rng.normal(size=(3, 3))
    u = block.nodes @ A.T
    np.testing.assert_allclose(t.displacement_at(pts, u), pts @ A.T, **TOL["interpolation"])
    with pytest.raises(InvalidInputError, match="outside the tissue"):
        t.displacement_at([[0.5, 0.5, 2.5]])


def test_point_force_and_reactions(block):
    t = TetTissue(block, MAT, block.face_nodes("z-"))
    F = np.array([[0.1, -0.2, 0.3]])
    f = t.point_forces([[0.5, 0.5, 1.7]], F)
    np.testing.assert_allclose(f.sum(0), F[0], **TOL["float64_exact"])
    u, info = t.solve_with_info(f)
    np.testing.assert_allclose(t.reactions(u).sum(0), -F[0], **TOL["fem_reactions"])
    # the reported residual is the evaluated one
    r = np.linalg.norm(t.residual(u, f))
    np.testing.assert_allclose(info.residual, r, **TOL["residual_norm"])
    assert info.residual <= TOL["newton_residual"]["rtol"] * np.linalg.norm(F)
    F_el = t.deformation_gradient_at(block.centroids)  # each centroid in its own element
    np.testing.assert_allclose(info.min_jacobian, np.linalg.det(F_el).min(), **TOL["float64_exact"])


@pytest.mark.parametrize("law", ["linear", "neo-hookean"])
def test_snapshot_restore_bit_for_bit(block, law):
    t = TetTissue(block, MAT, block.face_nodes("z-"), law=law)
    f1 = t.point_forces([[0.5, 0.5, 1.5]], [[0.0, 0.5, 0.0]])
    f2 = t.point_forces([[0.2, 0.5, 1.9]], [[0.4, 0.0, 0.0]])
    t.solve(f1)
    snap = t.snapshot()
    u2 = t.solve(f2)
    t.restore(snap)
    assert t.snapshot().identical(snap)
    u2b = t.solve(f2)
    assert u2b.tobytes() == u2.tobytes()


def test_with_material_reuses_assembly(block):
    t = TetTissue(block, MAT, block.face_nodes("z-"))
    f = t.point_forces([[0.5, 0.5, 1.5]], [[0.0, 0.5, 0.0]])
    t.solve(f)
    other = Material(20.0, 0.3)
    u_draw = t.with_material(other).solve(f)
    u_new = TetTissue(block, other, block.face_nodes("z-")).solve(f)
    np.testing.assert_allclose(u_draw, u_new, **TOL["float64_exact"])


def test_inverted_and_sliver_elements_are_named():
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    with pytest.raises(InvalidInputError, match=r"inverted element.*worst element 0"):
        TetMesh(nodes, [[0, 2, 1, 3]])
    sliver = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 1e-4]], dtype=float)
    with pytest.raises(InvalidInputError, match=r"worst element 0 with quality"):
        TetMesh(sliver, [[0, 1, 2, 3]])


def test_unsupported_body_and_bad_arguments(block):
    with pytest.raises(InvalidInputError, match="three nodes"):
        TetTissue(block, MAT, [0, 1])
    with pytest.raises(InvalidInputError, match="law"):
        TetTissue(block, MAT, block.face_nodes("z-"), law="svk")
    t = TetTissue(block, MAT, block.face_nodes("z-"))
    with pytest.raises(InvalidInputError, match="nodal_forces"):
        t.solve(np.zeros((3, 3)))


def test_nonconvergence_raises_and_keeps_state(block):
    t = TetTissue(block, MAT, block.face_nodes("z-"), law="neo-hookean", max_iter=1)
    before = t.snapshot()
    f = _face_load(block, "z+", (0.0, 0.0, 5.0))
    with pytest.raises(ConvergenceError):
        t.solve(f)
    assert t.snapshot().identical(before)


def test_fill_closed_surface_and_embedded_regions():
    trimesh = pytest.importorskip("trimesh")
    from riskplan.deformable import sphere_points, tet_fill_surface

    ball = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    m = tet_fill_surface(ball, n_elements=3000)
    assert abs(m.n_elements - 3000) <= 0.1 * 3000
    # the staircase lies within one lattice cell of the surface: the volume within the
    # shell of that thickness around the surface's own volume
    h = (6.0 * m.volume / m.n_elements) ** (1.0 / 3.0)
    assert abs(m.volume - ball.volume) <= ball.area * h
    assert np.all(ball.contains(m.centroids))
    t = TetTissue(m, MAT, m.nodes_in_box([-2, -2, -2], [2, 2, -0.6]))
    target = sphere_points([0.0, 0.0, 0.3], 0.1, 32)
    ip = t.interpolator(target, "target")
    u = t.solve(t.point_forces(target[:1], [[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(ip.positions(u), t.positions(target), **TOL["float64_exact"])
    with pytest.raises(InvalidInputError, match="obstacle: 1 point"):
        t.interpolator([[0.0, 0.0, 0.0], [0.0, 0.0, 1.5]], "obstacle")
    open_surface = trimesh.Trimesh(ball.vertices, ball.faces[:-10])
    with pytest.raises(InvalidInputError, match="watertight"):
        tet_fill_surface(open_surface, 1000)


@pytest.mark.parametrize("n", [200, 500, 1000, 2500, 5000])
def test_element_count_variation(n):
    """The mesh case: a requested count gives the nearest Kuhn-split grid (6 nx ny nz)."""
    m = tet_block((1.0, 1.0, 1.0), n_elements=n)
    assert m.n_elements % 6 == 0
    assert abs(m.n_elements - n) <= 0.12 * n
    assert m.qualities.min() > 0.4  # the Kuhn split of near-cubic cells


def test_mesh_case_converges_at_a_material_point():
    """The same point load on meshes of 500 .. 5000 elements moves a material point by
    amounts that settle as the mesh refines (what the mesh-count case varies)."""
    p, target = [[0.5, 0.5, 0.9]], [[0.5, 0.5, 0.6]]
    d = []
    for n in (500, 1500, 5000):
        m = tet_block(n_elements=n)
        t = TetTissue(m, MAT, m.face_nodes("z-"))
        d.append(t.displacement_at(target, t.solve(t.point_forces(p, [[0.1, 0.0, 0.0]])))[0, 0])
    assert d[0] > 0 and abs(d[2] - d[1]) < abs(d[1] - d[0])


def test_tissue_pickles_and_solves_the_same(block):
    import pickle

    t = TetTissue(block, MAT, block.face_nodes("z-"), law="neo-hookean")
    f = t.point_forces([[0.5, 0.5, 1.5]], [[0.0, 0.3, 0.0]])
    t.solve(f)
    t2 = pickle.loads(pickle.dumps(t))
    assert t2.snapshot().identical(t.snapshot())
    g = 1.5 * f
    assert t2.solve(g).tobytes() == t.solve(g).tobytes()


@pytest.mark.parametrize("law,scale", [("linear", 0.01), ("neo-hookean", 0.2)])
def test_prescribed_homogeneous_deformation_is_reproduced(block, law, scale):
    """A homogeneous deformation u = (F − I) X prescribed on the whole boundary is an
    equilibrium of any law: the interior nodes follow it (for the neo-Hookean law with
    strains of order 0.2, through the prescribed-motion predictor and Newton)."""
    rng = np.random.default_rng(3)
    H = scale * rng.normal(size=(3, 3))
    H = 0.5 * (H + H.T) + scale * np.eye(3)
    t = TetTissue(block, MAT, block.boundary_nodes, law=law)
    exact = block.nodes @ H.T
    u = t.solve(np.zeros((block.n_nodes, 3)), fixed_values=exact[t.fixed_nodes], load_steps=2)
    np.testing.assert_allclose(u, exact, **TOL["nonlinear_patch"])
    # the state pickles read-only and compares bit for bit
    import pickle

    snap = pickle.loads(pickle.dumps(t.snapshot()))
    assert snap.identical(t.snapshot()) and not snap.displacement.flags.writeable


def test_point_location_agrees_with_exhaustive_search():
    from riskplan.deformable.tetlocate import INSIDE_TOL, find_points

    m = tet_block(n_elements=5000)
    rng = np.random.default_rng(7)
    pts = np.vstack([rng.uniform(-0.05, 1.05, size=(400, 3)), m.nodes[:20]])
    elem, lam = find_points(m, pts)
    b = (
        np.einsum("tij,pj->pti", m.barycentric_maps[:, :, :3], pts)
        + m.barycentric_maps[None, :, :, 3]
    )
    best = b.min(axis=2).max(axis=1)
    np.testing.assert_array_equal(elem >= 0, best >= -INSIDE_TOL)
    inside = elem >= 0
    assert np.all(lam[inside].min(axis=1) >= -INSIDE_TOL)
    # the weights reproduce the point
    X = np.einsum("pa,pak->pk", lam[inside], m.nodes[m.tets[elem[inside]]])
    np.testing.assert_allclose(X, pts[inside], **TOL["float64_exact"])


@pytest.mark.parametrize("law", ["linear", "neo-hookean"])
def test_supports_that_leave_a_rigid_motion_free_are_refused(block, law):
    """Only the normal component held on z = 0: the body may slide and spin in that plane.
    The singular stiffness is refused, not answered with round-off."""
    with pytest.raises(InvalidInputError, match="rigid motion free"):
        TetTissue(block, MAT, fixed_dofs=3 * block.face_nodes("z-") + 2, law=law)
