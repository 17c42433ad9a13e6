"""riskplan: risk-aware motion planning for medical robots.

A shared core, two wings that never import each other, and the application layer:

* core: ``robots`` (Cosserat-rod tendon robots, hysteresis, simulated cameras), ``collision``
  (P(collision) of Gaussians and mixtures against meshes and polygons), ``gaussian_mixture``,
  ``geometry2d``, ``parallel``, ``io``, ``errors``;
* kinematic wing: ``datasets`` → ``kinematics`` (the mixture density network) → ``planning``
  (chest cavity and any robot: PRM, risk, Bayesian optimisation, validation);
* tissue wing: ``deformable`` (FEM) → ``scenarios`` (needle, manipulation) → ``control``
  (LQG, LQG-MP) → ``tissue_planning`` (simulator RRT, plan selection);
* application: ``app`` (demo, reproduce, command outputs, report), ``commands``, ``bench``,
  ``cli``.

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
