"""The needle scenario's tissue (:mod:`riskplan.scenarios.needle`): per-mesh data (mesh, base
linear model, locator, interpolation of the obstacles and the goal), the linear FEM model per
material with its flexibility (Green's) matrix, the tissue's response to the robot's push and
its finite-difference Jacobian, and the world pose of a material pose in a P1 element
(:func:`world_pose`)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["world_pose"]


def world_pose(material, u_element, lam, grad) -> np.ndarray:
    """The world pose ``(3,)`` of a material pose ``material (3,)`` = (X, Y, Θ) in a P1
    element with nodal displacements ``u_element (3, 2)``, barycentric weights ``lam (3,)``
    of ``X`` and shape-function gradients ``grad (3, 2)`` (``∇_X N_a``):

    .. math::

        x = X + \\sum_a \\lambda_a u_a, \\qquad
        F = I + \\sum_a u_a \\otimes \\nabla N_a, \\qquad
        \\theta = \\Theta + \\operatorname{atan2}(t \\times F t,\\; t \\cdot F t),
        \\quad t = (\\cos\\Theta, \\sin\\Theta).

    The heading is unwrapped about ``Θ`` (continuous along a path). No validation.

    Parameters
    ----------
    material : array_like, shape (3,)
        Material pose ``(X, Y, Θ)``.
    u_element : numpy.ndarray, shape (3, 2)
        Nodal displacements ``u_a`` of the element holding ``X``.
    lam : numpy.ndarray, shape (3,)
        Barycentric weights ``λ_a(X)``.
    grad : numpy.ndarray, shape (3, 2)
        Shape-function gradients ``∇_X N_a`` of the element.

    Returns
    -------
    numpy.ndarray, shape (3,)
        World pose ``(x, y, θ)``.
    """
    # plain floats: 3 x 2 numpy operations cost more than the arithmetic (planners' hot path)
    X, Y, th = np.asarray(material, dtype=np.float64).tolist()
    c, s = math.cos(th), math.sin(th)
    (u0x, u0y), (u1x, u1y), (u2x, u2y) = u_element.tolist()
    l0, l1, l2 = lam.tolist()
    (g0x, g0y), (g1x, g1y), (g2x, g2y) = grad.tolist()
    # directional derivative of u along t: (∇u) t = Σ_a u_a (∇N_a · t)
    d0, d1, d2 = g0x * c + g0y * s, g1x * c + g1y * s, g2x * c + g2y * s
    ftx = c + u0x * d0 + u1x * d1 + u2x * d2
    fty = s + u0y * d0 + u1y * d1 + u2y * d2
    dth = math.atan2(c * fty - s * ftx, c * ftx + s * fty)
    return np.array(
        [X + l0 * u0x + l1 * u1x + l2 * u2x, Y + l0 * u0y + l1 * u1y + l2 * u2y, th + dth]
    )


class MeshData:
    """Cached per element count: mesh, assembled stiffness parts (via a base model),
    point locator, and the interpolator of [obstacle vertices, goal polygon, goal centre]."""

    def __init__(self, cfg, n_elements: int):
        from riskplan.deformable import LinearElasticModel, Material, locate, mesh_polygon

        mesh = mesh_polygon(cfg.corners, n_elements)
        self.mesh = mesh
        self.base = LinearElasticModel(
            mesh, Material(50.0, 0.4, plane=cfg.plane), cfg.fixed_nodes(mesh)
        )
        self.locator = mesh.locator
        #: ``(n_elements, 3, 2)`` ∇_X of the P1 shape functions (the deformation gradient)
        self.shape_gradients = mesh.shape_gradients
        pts = np.concatenate(
            [*cfg.obstacles, cfg.goal_polygon, np.asarray(cfg.goal_center, dtype=np.float64)[None]]
        )
        self.interp = locate(mesh, pts)
        self.obstacle_slices = np.cumsum([0] + [len(p) for p in cfg.obstacles])
        k = int(self.obstacle_slices[-1])
        self.goal_slice = slice(k, k + 24)
        self.goal_center_index = k + 24

    def push_forces(self, material: np.ndarray, force_scale: float) -> np.ndarray:
        """Consistent nodal forces ``(n_nodes, 2)`` of the push ``f_int (cos Θ, sin Θ)`` at
        the material pose ``material (3,)`` (zero outside the tissue or without a push)."""
        f = np.zeros((self.mesh.n_nodes, 2))
        elem, lam = self.locator.locate(material[:2])
        if elem >= 0 and force_scale > 0:
            th = material[2]
            dirn = force_scale * np.array([math.cos(th), math.sin(th)])
            f[self.mesh.triangles[elem]] += lam[:, None] * dirn[None]
        return f


#: Free-DOF count up to which the dense flexibility matrix is kept (the planning mesh of
#: 175 elements has ~210); larger meshes solve with the sparse factorisation per step.
GREEN_MAX_DOFS = 700


class NeedleModel:
    """Cached per ``(E, ν, n_elements)``: the linear FEM model and, for meshes with at
    most ``GREEN_MAX_DOFS`` free DOFs, its flexibility (Green's) matrix over all DOFs, so a
    point load costs a 6-row gather. Which path a model uses depends only on its mesh,
    so results never depend on the cache history."""

    def __init__(self, data: MeshData, params, plane: str):
        from riskplan.deformable import Material

        self.data = data
        self.model = data.base.with_material(
            Material(params.youngs_modulus, params.poissons_ratio, plane=plane)
        )
        n = 2 * data.mesh.n_nodes
        tri = data.mesh.triangles
        #: ``(n_elements, 6)`` flat DOFs of each element's nodes, x then y (the load gather)
        self.element_dofs = np.concatenate([2 * tri, 2 * tri + 1], axis=1)
        self.element_dofs.setflags(write=False)
        free = self.model.free_dofs
        self.n_dofs = n
        self.green = None
        if len(free) <= GREEN_MAX_DOFS:
            green = np.zeros((n, n))
            # K_ff⁻¹ on the free DOFs; a force at a fixed DOF is taken by the support.
            # Symmetric, so row k is the displacement response to a unit force at DOF k.
            green[np.ix_(free, free)] = self.model.solve_free(np.eye(len(free)))
            green.setflags(write=False)
            self.green = green

    def response(self, dofs: np.ndarray, vals: np.ndarray) -> np.ndarray:
        """Displacement ``(n_nodes, 2)`` for nodal force values ``vals`` at flat ``dofs``."""
        if self.green is not None:
            return (vals @ self.green[dofs]).reshape(-1, 2)
        f = np.zeros(self.n_dofs)
        np.add.at(f, dofs, vals)
        return self.model.solve_flat(f).reshape(-1, 2)

    def push_response(self, mat: np.ndarray, force_scale: float):
        """New arrays ``(displacement (n_nodes, 2), world pose (3,))`` of the push
        ``force_scale · (cos Θ, sin Θ)`` at the material pose ``mat (3,)``."""
        d = self.data
        elem = -1
        if force_scale != 0.0:
            elem, lam = d.locator.locate(mat)  # reads mat[0], mat[1]
        if elem < 0:  # no push, or the robot has left the tissue: nothing moves it
            return np.zeros((d.mesh.n_nodes, 2)), mat.copy()
        th = float(mat[2])
        c, s = math.cos(th), math.sin(th)
        vals = np.empty(6)
        vals[:3] = lam * (force_scale * c)
        vals[3:] = lam * (force_scale * s)
        disp = self.response(self.element_dofs[elem], vals)
        pose = world_pose(mat, disp[d.mesh.triangles[elem]], lam, d.shape_gradients[elem])
        # heading: the material heading (riskplan.scenarios.needle: F's rotation is small,
        # and the P1 gradient jumps between elements, which finite differences would amplify)
        pose[2] = th
        return disp, pose

    def position_jacobian(self, mat: np.ndarray, force_scale: float, step: float) -> np.ndarray:
        """``(2, 3)`` central differences with ``step`` of the world position of the push
        response in the material pose ``mat (3,)``, the tissue's response recomputed at each
        perturbed pose."""
        H = np.zeros((2, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = step
            hi = self.push_response(mat + e, force_scale)[1][:2]
            lo = self.push_response(mat - e, force_scale)[1][:2]
            H[:, k] = (hi - lo) / (2.0 * step)
        return H
