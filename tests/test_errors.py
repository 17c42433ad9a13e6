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
