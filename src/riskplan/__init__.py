"""riskplan: risk-aware motion planning for medical robots.

Stages (one subpackage each, in pipeline order):

``robots``      Cosserat-rod tendon robots, hysteresis, simulated depth cameras
``datasets``    the data-collection protocol and HDF5 storage
``kinematics``  Gaussian mixtures and the mixture density network
``collision``   probability of collision of Gaussians / mixtures against meshes and polygons
``deformable``  FEM tissue simulators
``scenarios``   the planning scenarios of the papers (chest cavity, needle, manipulation)
``experiments`` paper figures, the demo and its HTML report

Heavy libraries are imported lazily by the subpackages that need them, so
``import riskplan`` stays cheap.
"""

__version__ = "0.1.0"

from riskplan.errors import (  # noqa: F401  (re-exported)
    ConvergenceError,
    ElementInversionError,
    InvalidInputError,
    RiskplanError,
)
