"""Isotropic elastic material parameters for 2-D tissue models (paper section III:
Young's modulus and Poisson's ratio are the uncertain material parameters).

Units: any consistent system; the paper's scenarios use E ~ 50 "units" with unit
forces on a unit square, and we keep that (E in force/length² for plane stress with
unit thickness, or force/length² per unit depth for plane strain).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from riskplan.errors import InvalidInputError

PLANES = ("stress", "strain")


# Larger than any real material (steel: 2e11 Pa) in any unit system used here, small enough that
# assembled stiffness entries (E times element factors) cannot overflow float64.
MAX_MODULUS = 1e30


@dataclass(frozen=True)
class Material:
    """Young's modulus ``E > 0``, Poisson's ratio ``-1 < nu < 0.5`` and the 2-D reduction.

    ``plane="stress"``: thin sheet of unit thickness (σ_zz = 0);
    ``plane="strain"``: long body (ε_zz = 0). Both give the same 2-D constitutive form
    σ = λ₂ tr(ε) I + 2 μ ε with μ = E / (2(1+ν)) and

    * plane strain: λ₂ = λ = E ν / ((1+ν)(1−2ν)),
    * plane stress: λ₂ = 2 λ μ / (λ + 2 μ) = E ν / (1 − ν²).

    The nonlinear models use the same (λ₂, μ) (see ``neohookean``).
    """

    E: float
    nu: float
    plane: str = "stress"

    def __post_init__(self):
        for name in ("E", "nu"):
            v = getattr(self, name)
            # strings ("50") and booleans are not numbers here, even if float() accepts them
            if isinstance(v, (bool, np.bool_)) or not isinstance(
                v, (numbers.Real, np.floating, np.integer)
            ):
                raise InvalidInputError(
                    f"{name}: expected a real number, got {v!r} ({type(v).__name__})"
                )
        E, nu = float(self.E), float(self.nu)
        if not math.isfinite(E) or not 0.0 < E <= MAX_MODULUS:
            raise InvalidInputError(
                f"E: Young's modulus must be finite, > 0 and <= {MAX_MODULUS:g} (stiffness matrices must stay finite), got {self.E!r}"
            )
        if not math.isfinite(nu) or not -1.0 < nu < 0.5:
            raise InvalidInputError(f"nu: Poisson's ratio must lie in (-1, 0.5), got {self.nu!r}")
        if self.plane not in PLANES:
            raise InvalidInputError(f"plane: expected one of {PLANES}, got {self.plane!r}")
        object.__setattr__(self, "E", E)
        object.__setattr__(self, "nu", nu)

    @property
    def mu(self) -> float:
        """Shear modulus μ = E / (2(1+ν))."""
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def lam3d(self) -> float:
        """Three-dimensional Lamé λ = E ν / ((1+ν)(1−2ν))."""
        return self.E * self.nu / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))

    @property
    def lam(self) -> float:
        """The 2-D Lamé λ₂ used in σ = λ₂ tr(ε) I + 2 μ ε (see class docstring)."""
        if self.plane == "strain":
            return self.lam3d
        return self.E * self.nu / (1.0 - self.nu**2)

    @property
    def lame(self) -> tuple[float, float]:
        """``(λ₂, μ)``."""
        return self.lam, self.mu
