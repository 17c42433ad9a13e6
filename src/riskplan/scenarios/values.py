"""The values that pass through a simulator of the deformable-planning method (Patil, van den
Berg & Alterovitz, RSS 2011, section III): the simulation parameters ``s`` (:class:`SimParams`,
one draw from a distribution S), the full system state ``y`` (:class:`SimState`), and the
actuation noise ``w_t`` a parameter set determines (:func:`actuation_noise`).

States and parameters hold read-only arrays (:func:`frozen_array`), so an RRT node can keep a
state and restart from it any number of times. The simulator seam itself (the
:class:`~riskplan.scenarios.base.Simulator` protocol, ``FEMScenario``) is in
:mod:`riskplan.scenarios.base`, which hands these names on.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from riskplan._validation import as_array, check_count
from riskplan.errors import InvalidInputError

__all__ = ["SimParams", "SimState", "actuation_noise", "frozen_array"]


def frozen_array(value, dtype=np.float64) -> np.ndarray:
    """A C-contiguous read-only copy of ``value`` (states and parameters hold these).

    Parameters
    ----------
    value : array_like
        Any shape.
    dtype : numpy dtype, optional
        Of the copy (default float64).

    Returns
    -------
    numpy.ndarray
        Same shape as ``value``, C order, ``writeable=False``; never a view of ``value``.
    """
    arr = np.array(value, dtype=dtype, copy=True, order="C")
    arr.setflags(write=False)
    return arr


def check_material(youngs_modulus, poissons_ratio) -> None:
    """Raise :class:`~riskplan.errors.InvalidInputError` unless the nominal material of a
    scenario's configuration is a finite ``youngs_modulus > 0`` and a ``poissons_ratio`` in
    ``(-1, 0.5)`` (a positive-definite isotropic elastic law)."""
    if not (0.0 < float(youngs_modulus) < math.inf):
        raise InvalidInputError(f"youngs_modulus: must be finite and > 0, got {youngs_modulus!r}")
    if not -1.0 < float(poissons_ratio) < 0.5:
        raise InvalidInputError(f"poissons_ratio: must lie in (-1, 0.5), got {poissons_ratio!r}")


@dataclass(frozen=True)
class SimParams:
    """Simulation parameters ``s`` of paper section III (one draw from a distribution S).

    Attributes
    ----------
    youngs_modulus:
        Young's modulus E of the tissue (> 0), in the paper's units (nominal 50).
    poissons_ratio:
        Poisson's ratio ν in (-1, 0.5) (nominal 0.4).
    n_elements:
        Requested number of triangles of the FEM mesh, in [8, 5000] (planning mesh: 175).
    force_scale:
        Interaction force scale (>= 0). Needle: the magnitude ``f_int`` of the force the
        robot exerts in its direction of motion (nominal 1). Manipulation: a gain on the
        commanded force increments (nominal 1).
    actuation_cov:
        ``None`` (no actuation noise) or an ``(m, m)`` covariance, stored as a tuple of
        tuples so the value stays hashable; the control actually applied at step ``t`` is
        ``u + w_t``, ``w_t ~ N(0, actuation_cov)``, clipped to the control bounds.
    actuation_seed:
        Seed of the actuation noise sequence; ``w_t`` is drawn from
        ``default_rng([actuation_seed, t])`` so it depends on the step index only.
    """

    youngs_modulus: float = 50.0
    poissons_ratio: float = 0.4
    n_elements: int = 175
    force_scale: float = 1.0
    actuation_cov: tuple[tuple[float, ...], ...] | None = None
    actuation_seed: int = 0

    def __post_init__(self):
        e = float(self.youngs_modulus)
        nu = float(self.poissons_ratio)
        f = float(self.force_scale)
        for name, v in (("youngs_modulus", e), ("poissons_ratio", nu), ("force_scale", f)):
            if not math.isfinite(v):
                raise InvalidInputError(f"{name}: must be finite, got {v!r}")
        if e <= 0.0:
            raise InvalidInputError(f"youngs_modulus: must be > 0, got {e:.6g}")
        if not (-1.0 < nu < 0.5):
            raise InvalidInputError(f"poissons_ratio: must lie in (-1, 0.5), got {nu:.6g}")
        if f < 0.0:
            raise InvalidInputError(f"force_scale: must be >= 0, got {f:.6g}")
        n = check_count(self.n_elements, "n_elements", 8, maximum=5000, integral=True)
        object.__setattr__(self, "youngs_modulus", e)
        object.__setattr__(self, "poissons_ratio", nu)
        object.__setattr__(self, "force_scale", f)
        object.__setattr__(self, "n_elements", n)
        object.__setattr__(self, "actuation_seed", int(self.actuation_seed))
        if self.actuation_cov is not None:
            cov = as_array(self.actuation_cov, "actuation_cov", min_ndim=2)
            if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
                raise InvalidInputError(
                    f"actuation_cov: expected a square (m, m) matrix, got shape {cov.shape}"
                )
            if not np.allclose(cov, cov.T, rtol=1e-12, atol=1e-15):
                raise InvalidInputError("actuation_cov: must be symmetric")
            if np.linalg.eigvalsh(cov).min() < -1e-14 * max(1.0, float(np.abs(cov).max())):
                raise InvalidInputError("actuation_cov: must be positive semi-definite")
            object.__setattr__(
                self, "actuation_cov", tuple(tuple(float(v) for v in row) for row in cov)
            )

    def replace(self, **changes) -> SimParams:
        """A copy with some fields changed (validated again).

        Parameters
        ----------
        **changes
            Field name → new value (``youngs_modulus``, ``n_elements``, ...).

        Returns
        -------
        SimParams
            The new parameter set; raises :class:`~riskplan.errors.InvalidInputError`
            when a changed value is invalid (as the constructor does).
        """
        return dataclasses.replace(self, **changes)

    @cached_property
    def actuation_factor(self) -> np.ndarray | None:
        """``(m, m)`` factor ``L`` with ``L Lᵀ = actuation_cov`` (eigen-based, so PSD is fine)."""
        if self.actuation_cov is None:
            return None
        cov = np.asarray(self.actuation_cov)
        w, v = np.linalg.eigh(cov)
        out = v * np.sqrt(np.clip(w, 0.0, None))
        out.setflags(write=False)
        return out

    @property
    def material_key(self) -> tuple[float, float, int]:
        """What identifies a FEM model: ``(E, ν, n_elements)``."""
        return (self.youngs_modulus, self.poissons_ratio, self.n_elements)


def actuation_noise(params: SimParams, t: int, m: int) -> np.ndarray | None:
    """The actuation noise ``w_t (m,)`` of step ``t`` under ``params``.

    Drawn from ``default_rng([params.actuation_seed, t])``: a pure function of the
    parameters and the step index, which keeps ``step`` deterministic (paper eq. 1).

    Parameters
    ----------
    params : SimParams
    t : int
        Step index.
    m : int
        Control dimension.

    Returns
    -------
    numpy.ndarray, (m,), or None
        ``None`` if the parameters carry no actuation noise.
    """
    factor = params.actuation_factor
    if factor is None:
        return None
    if factor.shape[0] != m:
        raise InvalidInputError(
            f"params.actuation_cov: expected a ({m}, {m}) covariance, got {factor.shape}"
        )
    z = np.random.default_rng([params.actuation_seed, int(t)]).standard_normal(m)
    return factor @ z


@dataclass(frozen=True, eq=False)
class SimState:
    """Full system state ``y_t`` (paper section III): everything needed to restart.

    Attributes
    ----------
    t:
        Step index (0 for the initial state).
    displacement:
        ``(n_nodes, 2)`` read-only FEM nodal displacement (warm start of the next solve).
    n_elements:
        The requested element count of the mesh ``displacement`` lives on; a state can
        only be continued with parameters whose ``n_elements`` matches.
    """

    t: int
    displacement: np.ndarray
    n_elements: int

    def __post_init__(self):
        object.__setattr__(self, "t", int(self.t))
        object.__setattr__(self, "n_elements", int(self.n_elements))
        object.__setattr__(self, "displacement", frozen_array(self.displacement))

    def __setstate__(self, state: dict) -> None:
        # unpickled arrays come back writeable: make them read-only again
        for k, v in state.items():
            if isinstance(v, np.ndarray):
                v.setflags(write=False)
            object.__setattr__(self, k, v)

    def arrays(self) -> dict[str, np.ndarray]:
        """All array fields by name (for comparisons and storage).

        Returns
        -------
        dict of str to numpy.ndarray
            The read-only arrays themselves (not copies): ``displacement (n_nodes, 2)`` and
            a subclass's arrays (a pose, applied forces, ...).
        """
        return {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if isinstance(getattr(self, f.name), np.ndarray)
        }

    def identical(self, other: SimState) -> bool:
        """Bit-for-bit equality of every field (the snapshot/restore contract).

        Parameters
        ----------
        other : SimState
            The state to compare with.

        Returns
        -------
        bool
            ``True`` when ``other`` has the same type and every field is equal; arrays are
            compared by shape, dtype and bytes (so ``-0.0`` differs from ``0.0`` and a NaN
            equals the same NaN).
        """
        if type(self) is not type(other):
            return False
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray):
                if a.shape != b.shape or a.dtype != b.dtype or a.tobytes() != b.tobytes():
                    return False
            elif a != b:
                return False
        return True
