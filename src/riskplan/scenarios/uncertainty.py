"""Parameter distributions S for the uncertainty cases of the deformable-planning paper
(Patil, van den Berg & Alterovitz, RSS 2011, section V-A, list of five cases).

Each case is a small frozen object with ``sample(seed) -> SimParams`` (alias
``sample_params``), ``sample_many(n, seed)``, the analytic ``mean``/``variance`` of the
quantity it varies, and ``planning_params`` — the parameters plans are made with (the
nominal material, the 175-element planning mesh, interaction force 1, no actuation noise).

Reading of the paper's numbers (written down because the paper does not say):

* ``N(a, b)`` is read as mean ``a`` and **variance** ``b``: E ~ N(50, 5) has standard
  deviation √5 ≈ 2.24, E ~ N(50, 75) has √75 ≈ 8.66; ν ~ N(0.4, 1e-4) has 0.01 and
  ν ~ N(0.4, 4e-4) has 0.02. (Read as standard deviations, E ~ N(50, 75) would give a
  negative Young's modulus in a quarter of the draws.) Draws are truncated to the
  physical range E > 0, ν ∈ (−1, 0.5) by redrawing; at these moments a redraw happens
  with probability below 1e-8, so the moments are those of the untruncated normals.
* Actuation noise: the covariance in our copy of the paper is illegible. We use
  ``diag(0.05², 0.0873²)`` for the needle's (v, φ): a standard deviation of 10 % of
  v_max = 0.5 and 5° of steering angle. For a scenario with other controls the noise is
  ``(0.1 · half-range of each control)²`` on the diagonal. The noisy control is clipped
  to the control bounds (actuator saturation; the car has no reverse).
* Mesh: the element count is uniform on the integers 50..1000. The paper says "the
  expected mesh contains 175 elements"; the mean of U{50..1000} is 525, so we read 175 as
  the mesh the planner uses (``planning_params.n_elements``), not as the mean.
* Interaction force: ``f_int ~ U[0, 2]`` (``force_scale``); for the manipulation scenario
  the same draw scales the commanded force increments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from riskplan._validation import as_array, as_generator, check_count
from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import SimParams

__all__ = [
    "CASE_NAMES",
    "ActuationNoise",
    "InteractionForceUncertainty",
    "MaterialUncertainty",
    "MeshUncertainty",
    "Nominal",
    "ParamDistribution",
    "WithActuation",
    "get_case",
    "needle_actuation_cov",
]

#: Names accepted by :func:`get_case` and the CLI ``--case`` option.
CASE_NAMES = ("nominal", "material-low", "material-high", "actuation", "mesh", "force")

#: Standard deviations of the needle's actuation noise (v, φ): 10 % of v_max, 5 degrees.
NEEDLE_ACTUATION_STD = (0.05, math.radians(5.0))


def needle_actuation_cov() -> tuple[tuple[float, float], tuple[float, float]]:
    """The needle's actuation covariance ``diag(0.05², (5°)²)`` (see module docstring).

    Returns
    -------
    tuple of tuple of float
        The 2 x 2 matrix, row by row.
    """
    sv, sp = NEEDLE_ACTUATION_STD
    return ((sv * sv, 0.0), (0.0, sp * sp))


@dataclass(frozen=True)
class ParamDistribution:
    """Base: a distribution S over :class:`SimParams` around ``base`` (the planning params)."""

    base: SimParams = field(default_factory=SimParams)
    name: str = "nominal"

    @property
    def planning_params(self) -> SimParams:
        """What the planner uses: ``base`` (expected deformation, no noise)."""
        return self.base

    def sample(self, seed=None) -> SimParams:
        """One draw ``s ~ S``; the same seed gives the same draw.

        Parameters
        ----------
        seed : int, numpy.random.Generator or None

        Returns
        -------
        SimParams
        """
        return self._draw(as_generator(seed))

    sample_params = sample

    def sample_many(self, n: int, seed=None) -> list[SimParams]:
        """``n`` independent draws from one generator seeded by ``seed``.

        Parameters
        ----------
        n : int
        seed : int, numpy.random.Generator or None

        Returns
        -------
        list of SimParams
        """
        n = check_count(n, "n", 0, integral=True)
        gen = as_generator(seed)
        return [self._draw(gen) for _ in range(n)]

    def _draw(self, gen: np.random.Generator) -> SimParams:
        return self.base


@dataclass(frozen=True)
class Nominal(ParamDistribution):
    """No uncertainty: every draw is ``base``."""

    name: str = "nominal"


def _truncated_normal(
    gen: np.random.Generator, mean: float, var: float, low: float, high: float
) -> float:
    sd = math.sqrt(var)
    for _ in range(10_000):
        v = mean + sd * float(gen.standard_normal())
        if low < v < high:
            return v
    raise InvalidInputError(
        f"cannot draw from N({mean}, {var}) inside ({low}, {high}): range too unlikely"
    )


@dataclass(frozen=True)
class MaterialUncertainty(ParamDistribution):
    """Case 1/2: ``E ~ N(E_mean, E_var)``, ``ν ~ N(nu_mean, nu_var)`` (independent; second
    argument a variance), truncated to E > 0 and ν ∈ (−1, 0.5)."""

    name: str = "material-low"
    youngs_mean: float = 50.0
    youngs_var: float = 5.0
    poisson_mean: float = 0.4
    poisson_var: float = 1e-4

    def __post_init__(self):
        if not (self.youngs_mean > 0 and self.youngs_var >= 0 and self.poisson_var >= 0):
            raise InvalidInputError(
                "MaterialUncertainty: need youngs_mean > 0 and non-negative variances"
            )
        if not -1.0 < self.poisson_mean < 0.5:
            raise InvalidInputError(f"poisson_mean: must lie in (-1, 0.5), got {self.poisson_mean}")

    @property
    def mean(self) -> tuple[float, float]:
        """``(E, ν)`` means."""
        return (self.youngs_mean, self.poisson_mean)

    @property
    def variance(self) -> tuple[float, float]:
        """``(E, ν)`` variances."""
        return (self.youngs_var, self.poisson_var)

    def _draw(self, gen):
        e = _truncated_normal(gen, self.youngs_mean, self.youngs_var, 0.0, math.inf)
        nu = _truncated_normal(gen, self.poisson_mean, self.poisson_var, -1.0, 0.5)
        return self.base.replace(youngs_modulus=e, poissons_ratio=nu)

    @classmethod
    def low(cls, base: SimParams | None = None) -> MaterialUncertainty:
        """Paper case 1: E ~ N(50, 5), ν ~ N(0.4, 1e-4).

        Around another nominal material ``base`` (a scenario file's): E ~ N(E₀, 5 (E₀/50)²) (the
        same relative spread), ν ~ N(ν₀, 1e-4).

        Parameters
        ----------
        base : SimParams, optional
            The nominal parameters (default: the paper's E = 50, ν = 0.4).

        Returns
        -------
        MaterialUncertainty
        """
        return cls._around(base, "material-low", 5.0, 1e-4)

    @classmethod
    def high(cls, base: SimParams | None = None) -> MaterialUncertainty:
        """Paper case 2: E ~ N(50, 75), ν ~ N(0.4, 4e-4); around another nominal material as
        :meth:`low` (variance 75 (E₀/50)²).

        Parameters
        ----------
        base : SimParams, optional
            The nominal parameters.

        Returns
        -------
        MaterialUncertainty
        """
        return cls._around(base, "material-high", 75.0, 4e-4)

    @classmethod
    def _around(cls, base, name, youngs_var, poisson_var) -> MaterialUncertainty:
        base = base or SimParams()
        r = base.youngs_modulus / 50.0  # exactly 1 for the paper's material
        return cls(
            base=base,
            name=name,
            youngs_mean=base.youngs_modulus,
            youngs_var=youngs_var * (r * r),
            poisson_mean=base.poissons_ratio,
            poisson_var=poisson_var,
        )


@dataclass(frozen=True)
class ActuationNoise(ParamDistribution):
    """Case 3: controls perturbed by ``w_t ~ N(0, cov)`` every step.

    A draw fixes the covariance and a fresh ``actuation_seed``; the noise sequence
    ``w_0, w_1, ...`` of that draw is then a pure function of the step index
    (:func:`riskplan.scenarios.base.actuation_noise`).
    """

    name: str = "actuation"
    cov: tuple[tuple[float, ...], ...] = field(default_factory=needle_actuation_cov)

    def __post_init__(self):
        cov = as_array(self.cov, "cov", min_ndim=2)
        if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
            raise InvalidInputError(f"cov: expected an (m, m) matrix, got {cov.shape}")
        object.__setattr__(self, "cov", tuple(tuple(float(v) for v in r) for r in cov))

    @property
    def variance(self) -> np.ndarray:
        """``(m, m)`` covariance of the per-step noise."""
        return np.asarray(self.cov)

    def _draw(self, gen):
        return self.base.replace(
            actuation_cov=self.cov, actuation_seed=int(gen.integers(0, 2**63 - 1))
        )


@dataclass(frozen=True)
class MeshUncertainty(ParamDistribution):
    """Case 4: element count uniform on the integers ``low..high`` (paper: 50..1000);
    planning uses ``base.n_elements`` (175)."""

    name: str = "mesh"
    low: int = 50
    high: int = 1000

    def __post_init__(self):
        if not (8 <= self.low <= self.high <= 5000):
            raise InvalidInputError(
                f"MeshUncertainty: need 8 <= low <= high <= 5000, got {self.low}, {self.high}"
            )

    @property
    def mean(self) -> float:
        return 0.5 * (self.low + self.high)

    @property
    def variance(self) -> float:
        n = self.high - self.low + 1
        return (n * n - 1) / 12.0

    def _draw(self, gen):
        return self.base.replace(n_elements=int(gen.integers(self.low, self.high + 1)))


@dataclass(frozen=True)
class InteractionForceUncertainty(ParamDistribution):
    """Case 5: interaction force ``f_int ~ U[low, high]`` (paper: U[0, 2])."""

    name: str = "force"
    low: float = 0.0
    high: float = 2.0

    def __post_init__(self):
        if not (0.0 <= self.low <= self.high and math.isfinite(self.high)):
            raise InvalidInputError(
                f"InteractionForceUncertainty: need 0 <= low <= high, got {self.low}, {self.high}"
            )

    @property
    def mean(self) -> float:
        return 0.5 * (self.low + self.high)

    @property
    def variance(self) -> float:
        return (self.high - self.low) ** 2 / 12.0

    def _draw(self, gen):
        return self.base.replace(force_scale=float(gen.uniform(self.low, self.high)))


@dataclass(frozen=True)
class WithActuation(ParamDistribution):
    """Another case's distribution with actuation noise added to every draw: the reading
    of the paper in which actuation noise acts in all five cases, not only in case 3.

    A draw is ``inner``'s draw with ``actuation_cov = cov`` and a fresh
    ``actuation_seed``; the planning parameters are ``inner``'s (plans assume no noise).
    """

    inner: ParamDistribution = field(default_factory=ParamDistribution)
    cov: tuple[tuple[float, ...], ...] = field(default_factory=needle_actuation_cov)
    name: str = ""

    def __post_init__(self):
        if not isinstance(self.inner, ParamDistribution):
            raise InvalidInputError(
                f"inner: expected a ParamDistribution, got {type(self.inner).__name__}"
            )
        cov = as_array(self.cov, "cov", min_ndim=2)
        if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
            raise InvalidInputError(f"cov: expected an (m, m) matrix, got {cov.shape}")
        object.__setattr__(self, "cov", tuple(tuple(float(v) for v in r) for r in cov))
        object.__setattr__(self, "base", self.inner.base)
        if not self.name:
            object.__setattr__(self, "name", f"{self.inner.name}+actuation")

    @property
    def planning_params(self) -> SimParams:
        return self.inner.planning_params

    def _draw(self, gen):
        p = self.inner._draw(gen)
        return p.replace(actuation_cov=self.cov, actuation_seed=int(gen.integers(0, 2**63 - 1)))


def get_case(name: str, base: SimParams | None = None, actuation_cov=None) -> ParamDistribution:
    """The distribution of one named case (:data:`CASE_NAMES`) around ``base``.

    Parameters
    ----------
    name : str
        A case name.
    base : SimParams, optional
        The nominal parameters.
    actuation_cov : array_like, (q, q), optional
        Overrides the needle's default actuation covariance (needed for a scenario whose
        control dimension is not 2; the scenarios pass their own).

    Returns
    -------
    ParamDistribution
    """
    base = base or SimParams()
    if name == "nominal":
        return Nominal(base=base)
    if name == "material-low":
        return MaterialUncertainty.low(base)
    if name == "material-high":
        return MaterialUncertainty.high(base)
    if name == "actuation":
        return ActuationNoise(
            base=base, cov=needle_actuation_cov() if actuation_cov is None else actuation_cov
        )
    if name == "mesh":
        return MeshUncertainty(base=base)
    if name == "force":
        return InteractionForceUncertainty(base=base)
    raise InvalidInputError(f"case: expected one of {', '.join(CASE_NAMES)}, got {name!r}")
