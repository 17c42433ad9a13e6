"""FEM tissue simulators (paper: Patil, van den Berg, Alterovitz, RSS 2011, sections III, V).

2-D P1 triangle meshes of a polygon with a requested element count, linear elasticity
with a cached factorisation, compressible neo-Hookean (and St Venant-Kirchhoff)
hyperelasticity with Newton's method, consistent nodal forces for point / patch /
body / traction loads, and barycentric interpolation at material points.
See ``docs/deformable.md`` for equations and the API.

Modules, one job each (imports point down this list, no cycles): ``elements`` (P1
geometry and kinematics, pure arrays), ``mesh`` (``TissueMesh`` with its cached derived
arrays, polygon meshing), ``material``, ``laws`` (hyperelastic energies, stresses,
tangents), ``banded`` (RCM + banded Cholesky), ``assembly`` (element forces/tangents,
DOF bookkeeping, sparse layouts), ``locate`` (material points), ``loads``, ``linear``
(linear model), ``newton`` (Newton with a line search, load stepping), ``hyperelastic``
(hyperelastic model); 3-D tissue:
``tetmesh`` (tetrahedral meshes, quality check), ``tissue3d`` (``TetTissue``: linear and
neo-Hookean P1 tetrahedra).
"""

from riskplan.deformable.hyperelastic import HyperelasticModel, NeoHookeanModel, SolveInfo
from riskplan.deformable.linear import LinearElasticModel, element_strains, element_stresses
from riskplan.deformable.loads import (
    body_load,
    patch_load,
    patch_weights,
    point_load,
    traction_load,
)
from riskplan.deformable.material import Material
from riskplan.deformable.material_points import Interpolator, contains, locate
from riskplan.deformable.mesh import TissueMesh, mesh_polygon, rectangle
from riskplan.deformable.tetlocate import sphere_points
from riskplan.deformable.tetmesh import TetMesh, tet_block, tet_fill_surface
from riskplan.deformable.tissue3d import TetTissue, TissueState3D

__all__ = [
    "HyperelasticModel",
    "Interpolator",
    "LinearElasticModel",
    "Material",
    "NeoHookeanModel",
    "SolveInfo",
    "TetMesh",
    "TetTissue",
    "TissueMesh",
    "TissueState3D",
    "body_load",
    "contains",
    "element_strains",
    "element_stresses",
    "locate",
    "mesh_polygon",
    "patch_load",
    "patch_weights",
    "point_load",
    "rectangle",
    "sphere_points",
    "tet_block",
    "tet_fill_surface",
    "traction_load",
]
