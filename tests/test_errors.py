import pytest

from riskplan import errors


@pytest.mark.parametrize(
    "cls, builtin",
    [
        (errors.InvalidInputError, ValueError),
        (errors.RobotDescriptionError, ValueError),
        (errors.DataFormatError, ValueError),
        (errors.ConvergenceError, RuntimeError),
        (errors.ElementInversionError, RuntimeError),
        (errors.MissingDependencyError, ImportError),
        (errors.PlanningError, RuntimeError),
        (errors.SimulationError, RuntimeError),
        (errors.NumericalError, ArithmeticError),
        (errors.BudgetError, ValueError),
        (errors.OutputLockedError, ValueError),
    ],
)
def test_hierarchy(cls, builtin):
    assert issubclass(cls, errors.RiskplanError)
    assert issubclass(cls, builtin)


def test_convergence_error_carries_residual():
    e = errors.ConvergenceError("no", residual=1e-3, iterations=7)
    assert e.residual == 1e-3 and e.iterations == 7


def test_require_names_extra():
    with pytest.raises(errors.MissingDependencyError, match=r"riskplan\[nope\]"):
        errors.require("riskplan_module_that_does_not_exist", "nope")


@pytest.mark.parametrize("seed", [-1, 1.5, "zero"])
def test_bad_seed_is_a_named_error(seed):
    # NumPy's own ValueError/TypeError used to reach the user as a traceback
    from riskplan._validation import as_generator
    from riskplan.planning.chest_scene import build_chest

    with pytest.raises(errors.InvalidInputError, match="seed"):
        as_generator(seed)
    with pytest.raises(errors.InvalidInputError, match="seed"):
        build_chest(seed, subdivisions=1)


@pytest.mark.parametrize("seed", [-1, 1.5, "zero"])
def test_bad_seed_of_the_tissue_planner_is_a_named_error(seed):
    # spawn_seeds (every parallel stage), the simulator RRT and the linearisation
    from riskplan.control import NominalPlan, linearize
    from riskplan.parallel import spawn_seeds
    from riskplan.scenarios.needle import NeedleScenario
    from riskplan.tissue_planning.rrt import rrt_plans

    sim = NeedleScenario()
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), sim.random_controls(3, seed=0))
    for call in (
        lambda: spawn_seeds(seed, 2),
        lambda: rrt_plans(sim, 1, seed=seed),
        lambda: linearize(sim, plan, [], seed=seed),
    ):
        with pytest.raises(errors.InvalidInputError, match="seed"):
            call()
    with pytest.raises(errors.InvalidInputError, match="n_steps"):
        sim.random_controls(-1, seed=0)


def test_good_seeds_give_the_numpy_generator():
    import numpy as np

    from riskplan._validation import as_generator

    g = np.random.default_rng(3)
    assert as_generator(g) is g
    assert as_generator(5).random() == np.random.default_rng(5).random()
    assert as_generator([5, 7]).random() == np.random.default_rng([5, 7]).random()
