"""One exception hierarchy for riskplan.

Every error the library raises on purpose derives from :class:`RiskplanError`, and
also from the builtin a caller would expect (``ValueError`` for bad arguments,
``RuntimeError`` for numerical failure, ``ImportError`` for a missing optional
dependency), so ``except ValueError`` keeps working for code that does not know
riskplan.

=============================  ==========================  =====================================
class                          builtin base                raised when
=============================  ==========================  =====================================
``InvalidInputError``          ``ValueError``              an argument has the wrong shape, type,
                                                           range, or is not finite
``RobotDescriptionError``      ``ValueError``              a robot TOML file is malformed (names
                                                           the key)
``DataFormatError``            ``ValueError``              a data set / model file is corrupted or
                                                           does not match what it is used with
``ConvergenceError``           ``RuntimeError``            an iterative solver did not converge
                                                           (carries the residual)
``ElementInversionError``      ``RuntimeError``            a finite element inverted (det F <= 0)
``MissingDependencyError``     ``ImportError``             an optional extra is not installed
``PlanningError``              ``RuntimeError``            a planner found no plan within its budget
                                                           (names the budget and how far it got)
``SimulationError``            ``RuntimeError``            a simulator returned a non-finite state
                                                           (names the step)
``BackendUnavailableError``    ``ConnectionError``         a parallel backend cannot be reached
                                                           (e.g. no Ray head at the address)
``NumericalError``             ``ArithmeticError``         a computation on finite input left
                                                           float64's range (names the step)
``BudgetError``                ``InvalidInputError``       a request exceeds a work budget
                                                           (names the estimate and the option)
``OutputLockedError``          ``ValueError``              another process is writing the same
                                                           output (choose another ``--out``)
=============================  ==========================  =====================================
"""

from __future__ import annotations

__all__ = [
    "BackendUnavailableError",
    "BudgetError",
    "ConvergenceError",
    "DataFormatError",
    "ElementInversionError",
    "InvalidInputError",
    "MissingDependencyError",
    "NumericalError",
    "OutputLockedError",
    "PlanningError",
    "RiskplanError",
    "RobotDescriptionError",
    "SimulationError",
    "require",
]


class RiskplanError(Exception):
    """Base class of every error raised on purpose by riskplan."""


class InvalidInputError(RiskplanError, ValueError):
    """An argument is malformed: wrong shape, type or range, or not finite.

    The message names the argument and what was expected.
    """


class RobotDescriptionError(InvalidInputError):
    """A robot description (TOML) is malformed; ``key`` names the offending entry."""

    def __init__(self, message: str, key: str | None = None):
        super().__init__(message)
        self.key = key


class DataFormatError(InvalidInputError):
    """A file (data set, model checkpoint) is corrupted or does not match its use."""


class ConvergenceError(RiskplanError, RuntimeError):
    """An iterative solver stopped without meeting its tolerance.

    Attributes
    ----------
    residual:
        The last residual norm the solver reached (``None`` if not applicable).
    iterations:
        Iterations performed.
    """

    def __init__(self, message: str, residual: float | None = None, iterations: int | None = None):
        super().__init__(message)
        self.residual = residual
        self.iterations = iterations


class ElementInversionError(RiskplanError, RuntimeError):
    """A finite element inverted (``det F <= 0``) during a nonlinear solve.

    Attributes
    ----------
    elements:
        Indices of the inverted elements.
    min_jacobian:
        The smallest ``det F`` seen.
    """

    def __init__(self, message: str, elements=None, min_jacobian: float | None = None):
        super().__init__(message)
        self.elements = elements
        self.min_jacobian = min_jacobian


class MissingDependencyError(RiskplanError, ImportError):
    """An optional dependency is needed for this feature but is not installed."""


class PlanningError(RiskplanError, RuntimeError):
    """A planner found no acceptable plan within its budget.

    The message names the budget (time, iterations, roadmap or tree size) and how far the
    planner got (e.g. the best distance to the goal), so the user knows what to change.
    """


class SimulationError(RiskplanError, RuntimeError):
    """A simulator produced a non-finite or otherwise unusable state; the message names the step."""


class BackendUnavailableError(RiskplanError, ConnectionError):
    """A parallel backend cannot be used: e.g. no Ray head answers at the given address."""


class NumericalError(RiskplanError, ArithmeticError):
    """A computation on finite input overflowed float64 or produced NaN (e.g. a Riccati
    recursion with an unstable, huge ``A``).

    Attributes
    ----------
    step:
        Where it happened (the step of a recursion), ``None`` if not applicable.
    """

    def __init__(self, message: str, step: int | None = None):
        super().__init__(message)
        self.step = step


class BudgetError(InvalidInputError):
    """A request would exceed a work budget (memory, or a count of work units); the message
    names the estimate, the ceiling and the option that sets it (see :mod:`riskplan.budget`)."""


class OutputLockedError(InvalidInputError):
    """Another live process holds the lock of an output (one writer per output folder or
    file); the message names its process id."""


def require(module: str, extra: str):
    """Import ``module`` or raise :class:`MissingDependencyError` naming the pip extra.

    Parameters
    ----------
    module : str
        The module's dotted name.
    extra : str
        The pip extra that installs it.

    Returns
    -------
    module
        The imported module.
    """
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingDependencyError(
            f"{module!r} is required for this feature; install it with "
            f"`pip install 'riskplan[{extra}]'`"
        ) from exc
