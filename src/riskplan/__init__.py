"""riskplan: risk-aware motion planning for medical robots.

A shared core, two wings that never import each other, and the application layer:

* core: ``robots`` (Cosserat-rod tendon robots, hysteresis, simulated cameras), ``collision``
  (P(collision) of Gaussians and mixtures against meshes and polygons), ``gaussian_mixture``,
  ``geometry2d``, ``parallel``, ``io``, ``errors``;
* kinematic wing: ``datasets`` → ``kinematics`` (the mixture density network) → ``planning``
  (chest cavity and any robot: PRM, risk, Bayesian optimisation, validation);
* tissue wing: ``deformable`` (FEM) → ``scenarios`` (needle, manipulation) → ``control``
  (LQG, LQG-MP) → ``tissue_planning`` (simulator RRT, plan selection, the 3-D needle);
* application: ``app`` (demo, reproduce, command outputs, report), ``commands``, ``bench``,
  ``cli``.

The public face: the calls a user starts from, on the package itself and loaded on first
use (PEP 562), so ``import riskplan`` stays fast and imports neither torch nor the FEM::

    import riskplan as rp

    robot = rp.load_robot("paper")                     # riskplan.robots
    model = rp.load_model("model.pt", robot)           # riskplan.kinematics
    p = rp.probability_of_collision(mixture, env)      # riskplan.collision
    plan = rp.plan_chest(model, chest)                 # riskplan.planning
    sim = rp.make_scenario("needle", "material-high")  # riskplan.scenarios
    result = rp.plan_tissue("needle", n_plans=20)      # riskplan.tissue_planning
    result = rp.plan_needle3d("actuation")             # riskplan.tissue_planning (the 3-D needle)

Each name is defined in the module :data:`PUBLIC` names; the reference documents it there.

Heavy libraries are imported lazily by the subpackages that need them, so
``import riskplan`` stays cheap.
"""

__version__ = "0.1.0"

from riskplan.errors import (
    ConvergenceError,
    ElementInversionError,
    InvalidInputError,
    RiskplanError,
)

#: the public face: name -> the module that defines it (imported on first use)
PUBLIC = {
    # core
    "load_robot": "riskplan.robots",
    "TendonRobot": "riskplan.robots",
    "RobotParams": "riskplan.robots",
    "NumpyMixture": "riskplan.gaussian_mixture",
    "KinematicsModel": "riskplan.kinematics_model",
    "Environment": "riskplan.collision",
    "load_environment": "riskplan.collision",
    "probability_of_collision": "riskplan.collision",
    # kinematic wing
    "generate_splits": "riskplan.datasets",
    "load_dataset": "riskplan.datasets",
    "GaussianMixture": "riskplan.kinematics",
    "MDNModel": "riskplan.kinematics",
    "load_model": "riskplan.kinematics",
    "save_model": "riskplan.kinematics",
    "TrainConfig": "riskplan.kinematics",
    "train": "riskplan.kinematics",
    "build_chest": "riskplan.planning",
    "plan_chest": "riskplan.planning",
    "plan_robot": "riskplan.planning",
    "load_problem": "riskplan.planning",
    # tissue wing
    "make_scenario": "riskplan.scenarios",
    "NominalPlan": "riskplan.control",
    "linearize": "riskplan.control",
    "lqg_controller": "riskplan.control",
    "lqgmp": "riskplan.control",
    "rrt_plans": "riskplan.tissue_planning",
    "select_plan": "riskplan.tissue_planning",
    "plan_tissue": "riskplan.tissue_planning",
    "plan_needle3d": "riskplan.tissue_planning",
}

__all__ = [
    "ConvergenceError",
    "ElementInversionError",
    "InvalidInputError",
    "RiskplanError",
    "__version__",
    *sorted(PUBLIC),
]


def __getattr__(name: str):
    module = PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'riskplan' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(PUBLIC))
