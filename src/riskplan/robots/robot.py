"""``TendonRobot``: the validating facade over the Cosserat kernels (:mod:`riskplan.robots.cosserat`).

It caches the per-robot arrays (routing polynomials, stiffness diagonals, rest lengths),
checks inputs once at the boundary and places results in the world by the base pose.
"""

from __future__ import annotations

import functools
import logging
import math
import os
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np
from numba import njit

from riskplan._validation import as_array, check_range
from riskplan.errors import ConvergenceError, InvalidInputError, RobotDescriptionError
from riskplan.robots import cosserat
from riskplan.robots.description import parse_robot_toml, read_robot_text
from riskplan.robots.params import (
    BaseMotion,
    Disks,
    Gravity,
    RobotParams,
    params_to_toml,
    rpy_to_matrix,
)
from riskplan.robots.pose import BasePose, quaternion_to_matrix
from riskplan.robots.rod_tables import LOCAL_MAXIT, LOCAL_TOL

__all__ = [
    "PACKAGED_ROBOTS",
    "RodShape",
    "TendonRobot",
    "cached_robot",
    "load_robot",
    "robot_from_toml",
]

log = logging.getLogger(__name__)

PACKAGED_ROBOTS = {"paper": "paper_robot.toml"}

DISP_TOL = 1e-12  # m, complementarity residual of the displacement -> tension solve
DISP_MAXIT = 60
SHOOT_TOL = 1e-11  # N m, tip-moment residual of the shooting solve
SHOOT_MAXIT = 30
# Batches at least this large use the configuration-vectorised kernel (faster from ~8 on).
BATCH_KERNEL_MIN = 8


@dataclass(frozen=True, eq=False)
class RodShape:
    """Robot shape(s) in the world frame (= base frame for the default base pose).

    Attributes
    ----------
    s : (n,) arc length of the stations [m], from the exposed base; ``(..., n)`` for a batch
        solved with per-configuration ``retraction`` (each exposed length has its own stations)
    positions : (..., n, 3) backbone points [m]
    rotations : (..., n, 3, 3) body frames; columns are the body axes (z = backbone tangent
        direction of the unsheared rod)
    tensions : (..., m) tendon tensions [N]
    """

    s: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray
    tensions: np.ndarray

    @property
    def tip(self) -> np.ndarray:
        """``(..., 3)`` tip position."""
        return self.positions[..., -1, :]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.tensions.shape[:-1]

    def __getitem__(self, idx) -> RodShape:
        if not self.batch_shape:
            raise InvalidInputError("RodShape: a single shape cannot be indexed")
        s = self.s if self.s.ndim == 1 else self.s[idx]
        return RodShape(s, self.positions[idx], self.rotations[idx], self.tensions[idx])

    def to_json(self) -> dict:
        """``{"tip", "backbone", "tensions"}`` of a single shape (plain lists)."""
        if self.batch_shape:
            raise InvalidInputError("to_json: expected a single shape; index the batch first")
        return {
            "tip": self.tip.tolist(),
            "backbone": self.positions.tolist(),
            "tensions": self.tensions.tolist(),
        }


@njit(cache=True)
def in_limits(values, low, high):
    """True if every entry of the C-contiguous ``values (..., m)`` is finite and within
    ``low[j] <= values[..., j] <= high[j]`` (a sub-microsecond check for the facade's fast path;
    the facade falls back to the numpy checks, which name the offending entry)."""
    m = low.shape[0]
    flat = values.reshape(-1)
    for k in range(flat.shape[0]):
        x = flat[k]
        if not (x >= low[k % m] and x <= high[k % m]):  # NaN fails both comparisons
            return False
    return True


def shift_polynomial(coefficients, offset: float) -> tuple[float, ...]:
    """Coefficients of ``q(x) = p(x + offset)`` for ``p(x) = sum_k c_k x^k`` (ascending powers).

    A retracted robot's routing ``theta(s)``, ``r(s)`` at absolute arc length ``s = s' + rho``
    is the same-degree polynomial of the exposed arc length ``s'``.
    """
    P = np.polynomial.Polynomial(np.asarray(coefficients, dtype=np.float64))
    q = P(np.polynomial.Polynomial([float(offset), 1.0])).coef
    out = np.zeros(len(coefficients))
    out[: len(q)] = q
    return tuple(float(v) for v in out)


def rotation_z(angle) -> np.ndarray:
    """``(..., 3, 3)`` rotations about z by ``angle (...)`` [rad] (right-handed)."""
    a = np.asarray(angle, dtype=np.float64)
    c, s_ = np.cos(a), np.sin(a)
    out = np.zeros(a.shape + (3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s_, s_, c
    out[..., 2, 2] = 1.0
    return out


def _poly_table(polys) -> np.ndarray:
    K = max(len(c) for c in polys)
    out = np.zeros((len(polys), K))
    for i, c in enumerate(polys):
        out[i, : len(c)] = c
    return out


class TendonRobot:
    """A tendon-driven continuum robot described by :class:`RobotParams`.

    >>> robot = load_robot("paper")
    >>> robot.solve_displacements([0.01, 0, 0, 0]).tip.shape
    (3,)
    """

    def __init__(self, params: RobotParams, toml_text: str | None = None):
        self.params = params
        self._toml = toml_text
        bb = params.backbone
        self._n = bb.n_steps
        self._L = bb.length
        self._theta = _poly_table([t.theta for t in params.tendons])
        self._radius = _poly_table([t.radius for t in params.tendons])
        #: the per-robot arrays every Cosserat kernel takes (:class:`cosserat.RodTables`)
        self.tables = cosserat.rod_tables(
            self._theta, self._radius, bb.kse, bb.kbt, self._L, self._n
        )
        self._kinv = np.array(
            [0.0 if math.isinf(t.stiffness) else 1.0 / t.stiffness for t in params.tendons]
        )
        m = self.n_tendons
        self._l0 = np.empty(m)
        dl = np.empty((m, m))
        st = cosserat.lengths_and_jacobian(
            np.zeros(m), *self.tables, LOCAL_TOL, LOCAL_MAXIT, self._l0, dl
        )
        if st != cosserat.OK:  # pragma: no cover - the straight rod always solves
            raise ConvergenceError("rest-length computation failed")
        self._G0 = -dl  # d(shortening)/d tau at tau = 0, used for start values
        # Start of the displacement solve: the linearisation at tau = 0, (G0 + diag(1/k)) tau = d.
        # A pseudo-inverse, since with inextensible antagonistic tendons this matrix is singular
        # up to round-off (the rod's axial stiffness alone separates the tendons).
        self._A0pinv = np.linalg.pinv(self._G0 + np.diag(self._kinv), rcond=1e-10)
        d = params.disks
        self._lam = bb.density * bb.area + d.count * d.mass / bb.length
        # cached for the hot path (validation and output)
        self._tmax = np.array([t.max_tension for t in params.tendons], dtype=float)
        self._tlow = np.zeros(len(params.tendons))
        dlim = np.array([t.displacement_limits for t in params.tendons], dtype=float)
        self._dlo, self._dhi = dlim[:, 0].copy(), dlim[:, 1].copy()  # contiguous, for in_limits
        self._s = np.linspace(0.0, self._L, self._n + 1)
        self._s.flags.writeable = False  # shared by every RodShape this robot returns
        self._identity_base = params.base.is_identity

    # ------------------------------------------------------------------ description
    @property
    def name(self) -> str:
        return self.params.name

    @property
    def n_tendons(self) -> int:
        return len(self.params.tendons)

    @property
    def n_stations(self) -> int:
        return self._n + 1

    @property
    def s(self) -> np.ndarray:
        """``(n,)`` arc length of the output stations [m]."""
        return self._s.copy()

    @property
    def displacement_limits(self) -> np.ndarray:
        """``(m, 2)`` ``[low, high]`` per tendon [m]."""
        return np.stack([self._dlo, self._dhi], axis=1)

    @property
    def tension_limits(self) -> np.ndarray:
        """``(m,)`` maximum tension per tendon [N]."""
        return self._tmax.copy()

    @property
    def base_motion(self) -> BaseMotion:
        """Which base variables (rotation, retraction) the configuration holds, and their limits."""
        return self.params.base_motion

    @property
    def n_config(self) -> int:
        """Configuration size: tendons, then rotation (if enabled), then retraction (if enabled)."""
        return self.n_tendons + self.params.base_motion.n_extra

    @property
    def configuration_limits(self) -> np.ndarray:
        """``(n_config, 2)`` ``[low, high]``: tendon displacements [m], then rotation [rad] and
        retraction [m] where enabled (the lab's configuration order)."""
        rows = [self.displacement_limits]
        bm = self.base_motion
        if bm.rotation:
            rows.append(np.array([bm.rotation_limits]))
        if bm.retraction:
            rows.append(np.array([bm.retraction_limits]))
        return np.concatenate(rows, axis=0)

    def split_configuration(self, q, *, validate: bool = True):
        """``(tendon_part (..., m), rotation (...) or None, retraction (...) or None)`` of
        configurations ``q (..., n_config)`` in the lab's order (tendons, rotation, retraction)."""
        q = as_array(q, "configuration", min_ndim=1) if validate else np.asarray(q, dtype=float)
        if q.shape[-1] != self.n_config:
            raise InvalidInputError(
                f"configuration: expected last dimension {self.n_config} ({self.n_tendons} tendons"
                f"{' + rotation' if self.base_motion.rotation else ''}"
                f"{' + retraction' if self.base_motion.retraction else ''}), got shape {q.shape}"
            )
        m = self.n_tendons
        rot = q[..., m] if self.base_motion.rotation else None
        ret = q[..., -1] if self.base_motion.retraction else None
        return q[..., :m], rot, ret

    @property
    def tendon_rest_lengths(self) -> np.ndarray:
        """``(m,)`` tendon path lengths along the straight unloaded backbone [m]."""
        return self._l0.copy()

    @property
    def loaded(self) -> bool:
        """True when gravity is on (the shooting solver is used)."""
        return bool(
            self.params.gravity.enabled and self._lam > 0 and any(self.params.gravity.vector)
        )

    def toml_text(self) -> str:
        """The robot file (TOML) that rebuilds this robot."""
        return self._toml if self._toml is not None else params_to_toml(self.params)

    def with_base_pose(
        self, position=(0.0, 0.0, 0.0), *, rotation=None, rpy=None, quaternion=None
    ) -> TendonRobot:
        """The same robot with another base pose (give one of rotation matrix, rpy, quaternion)."""
        given = [
            k
            for k, v in (("rotation", rotation), ("rpy", rpy), ("quaternion", quaternion))
            if v is not None
        ]
        if len(given) > 1:
            raise InvalidInputError(f"with_base_pose: give one orientation, got {given}")
        pos = as_array(position, "position", shape=(3,))
        if rotation is not None:
            Rm = as_array(rotation, "rotation", shape=(3, 3))
            if not np.allclose(Rm.T @ Rm, np.eye(3), atol=1e-8) or np.linalg.det(Rm) <= 0:
                raise InvalidInputError(
                    "rotation: expected a proper rotation matrix (R^T R = I, det R = 1)"
                )
        elif quaternion is not None:
            q = as_array(quaternion, "quaternion", shape=(4,))
            if np.linalg.norm(q) < 1e-12:
                raise InvalidInputError("quaternion: must be non-zero")
            Rm = quaternion_to_matrix(q)
        else:
            Rm = rpy_to_matrix(as_array(rpy if rpy is not None else (0, 0, 0), "rpy", shape=(3,)))
        base = BasePose(tuple(float(v) for v in pos), tuple(tuple(float(v) for v in r) for r in Rm))
        return TendonRobot(replace(self.params, base=base))

    def with_gravity(self, enabled: bool = True, vector=None) -> TendonRobot:
        """The same robot with gravity switched on/off (``vector`` in the world frame, m/s^2)."""
        if not isinstance(enabled, (bool, np.bool_)):
            raise InvalidInputError(
                f"enabled: expected True or False, got {enabled!r} ({type(enabled).__name__})"
            )
        vec = (
            self.params.gravity.vector
            if vector is None
            else tuple(as_array(vector, "vector", shape=(3,)).tolist())
        )
        return TendonRobot(replace(self.params, gravity=Gravity(bool(enabled), vec)))

    def __repr__(self) -> str:
        return f"TendonRobot(name={self.name!r}, tendons={self.n_tendons}, length={self._L})"

    # ---------------------------------------------------------------------- checks
    def _check(self, value, name, low, high):
        """``value (..., m)`` as a float array within ``[low, high]`` (per-tendon arrays ``(m,)``)."""
        # fast path: a well-formed array passes with one compiled loop (no temporaries)
        if (
            isinstance(value, np.ndarray)
            and value.dtype == np.float64
            and value.ndim >= 1
            and value.shape[-1] == self.n_tendons
            and value.flags.c_contiguous
        ):
            if in_limits(value, low, high):
                return value
        arr = as_array(value, name, min_ndim=1)
        if arr.shape[-1] != self.n_tendons:
            raise InvalidInputError(
                f"{name}: expected last dimension {self.n_tendons} (one per tendon), got shape {arr.shape}"
            )
        check_range(arr, name, low=low, high=high)
        return arr

    def check_tensions(self, tensions) -> np.ndarray:
        """``tensions (..., m)`` as a float array in ``[0, max_tension]``, else :class:`InvalidInputError`."""
        return self._check(tensions, "tensions", self._tlow, self._tmax)

    def check_displacements(self, displacements) -> np.ndarray:
        """``displacements (..., m)`` as a float array within the limits, else :class:`InvalidInputError`."""
        return self._check(displacements, "displacements", self._dlo, self._dhi)

    def _to_world(self, P, Rs, tau, batch) -> RodShape:
        base = self.params.base
        n = self._n + 1
        if not self._identity_base:
            Rb = base.matrix
            P = P @ Rb.T + np.asarray(base.position)
            Rs = np.einsum("ij,...jk->...ik", Rb, Rs)
        return RodShape(
            self._s,
            P.reshape(batch + (n, 3)),
            Rs.reshape(batch + (n, 3, 3)),
            tau.reshape(batch + (self.n_tendons,)),
        )

    def _gravity_base(self) -> np.ndarray:
        """Distributed force per unit length in the base frame [N/m]."""
        return self._lam * (
            self.params.base.matrix.T @ np.asarray(self.params.gravity.vector, dtype=float)
        )

    def _batch_input(self, values, check, validate: bool):
        """``(flat, batch)``: ``values (..., m)``, checked by ``check`` when ``validate``, as a
        C-contiguous float array ``flat (B, m)``, and the leading shape ``batch``."""
        a = check(values) if validate else np.asarray(values, dtype=float)
        return np.ascontiguousarray(a.reshape(-1, self.n_tendons)), a.shape[:-1]

    # ---------------------------------------------------------------------- solving
    def solve_tensions(
        self, tensions, *, rotation=None, retraction=None, validate: bool = True
    ) -> RodShape:
        """Shape for tendon tensions ``(..., m)`` [N], ``0 <= tension <= max_tension``.

        ``rotation`` [rad] and ``retraction`` [m] (scalars or ``(...)``, robots whose file
        enables them; see :class:`~riskplan.robots.params.BaseMotion`): the exposed arc
        ``[retraction, L]`` is solved as a robot of its own (:meth:`retracted`), then turned
        about the base z axis by ``rotation``.

        Without gravity: local strain solves of eqs. (2)-(3) and one RK4 pass
        (:func:`cosserat.shape_free`; batches of ``BATCH_KERNEL_MIN`` or more go through the
        SIMD kernel of :mod:`riskplan.robots.batch_kernel`, same results); with gravity: shooting on the base moment
        (:func:`cosserat.shape_loaded`). Raises :class:`ConvergenceError` if a solve fails.

        Parameters
        ----------
        tensions : array_like
            ``(..., m)`` tendon tensions [N].
        rotation, retraction : float or array_like, optional
            Base rotation [rad] and retraction [m] (scalars or ``(...)``).
        validate : bool
            Check the arguments (``False`` for internal callers with checked arguments).

        Returns
        -------
        RodShape
            Backbone positions and frames of batch shape ``(...)``.
        """
        if rotation is not None or retraction is not None:
            return self._solve_moved(True, tensions, rotation, retraction, validate)
        tau = self.check_tensions(tensions) if validate else np.asarray(tensions, dtype=float)
        if tau.ndim == 1 and not self.loaded:
            return self._solve_single_free(tau)
        batch = tau.shape[:-1]
        flat = np.array(
            tau.reshape(-1, self.n_tendons), dtype=np.float64, order="C"
        )  # a copy: the shape owns it
        B, n, m = flat.shape[0], self._n + 1, self.n_tendons
        P = np.empty((B, n, 3))
        Rs = np.empty((B, n, 3, 3))
        if not self.loaded and B >= BATCH_KERNEL_MIN:
            # Same algorithm, vectorised across configurations (bit-identical results).
            from riskplan.robots.batch_kernel import solve_tensions_batch

            P, Rs = solve_tensions_batch(self, flat, parallel=False, validate=False)
        elif not self.loaded:
            lengths = np.empty((B, m))
            status = np.empty(B, dtype=np.int64)
            cosserat.shape_free_batch(
                flat, *self.tables, LOCAL_TOL, LOCAL_MAXIT, P, Rs, lengths, status
            )
            bad = np.flatnonzero(status != cosserat.OK)
            if bad.size:
                raise self.local_failure_error(flat[bad[0]])
        else:
            for b in range(B):
                Y = self._shoot(flat[b])
                P[b] = Y[:, 0:3]
                Rs[b] = Y[:, 3:12].reshape(n, 3, 3)
        if not np.isfinite(P).all():  # never hand out NaN silently
            b = int(np.flatnonzero(~np.isfinite(P).reshape(B, -1).all(-1))[0])
            raise ConvergenceError(f"non-finite shape for tensions {flat[b].tolist()}")
        return self._to_world(P, Rs, flat, batch)

    def _solve_single_free(self, tau) -> RodShape:
        """One configuration without external loads: the scalar kernel, no batch bookkeeping."""
        tau = np.array(tau, dtype=np.float64)  # a copy: the shape owns it
        n, m = self._n + 1, self.n_tendons
        P = np.empty((n, 3))
        Rs = np.empty((n, 3, 3))
        st = cosserat.shape_free(
            tau, *self.tables, LOCAL_TOL, LOCAL_MAXIT, P, Rs, np.empty((n, 6)), np.empty(m)
        )
        if st != cosserat.OK:
            raise self.local_failure_error(tau)
        # a non-finite value anywhere propagates along the RK4 pass to the tip position
        if not math.isfinite(P[-1, 0] + P[-1, 1] + P[-1, 2]):
            raise ConvergenceError(f"non-finite shape for tensions {tau.tolist()}")
        return self._to_world(P, Rs, tau, ())

    def interpolate_configurations(self, a, b, t) -> np.ndarray:
        """``(..., n_config)`` points ``a + t (b - a)`` of the straight configuration-space motion
        from ``a`` to ``b`` (``t`` scalar or ``(...)``, in [0, 1]); a base rotation over a full
        turn takes the short way round and is wrapped into ``[-pi, pi)`` (the lab's
        ``VoxelEnvironment`` interpolation with ``util::canonical_angle``)."""
        a = np.asarray(a, dtype=np.float64)
        b = np.asarray(b, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64)[..., None]
        out = a + t * (b - a)
        bm = self.base_motion
        if bm.rotation and bm.rotation_limits[1] - bm.rotation_limits[0] >= 2 * math.pi - 1e-12:
            j = self.n_tendons
            diff = np.mod(b[..., j] - a[..., j] + math.pi, 2 * math.pi) - math.pi
            out[..., j] = np.mod(a[..., j] + t[..., 0] * diff + math.pi, 2 * math.pi) - math.pi
        return out

    def configuration_to_displacements(self, q, *, validate: bool = True) -> np.ndarray:
        """A configuration in tension form ``(..., n_config)`` (tensions [N], then rotation and
        retraction) in displacement form (tendon displacements [m] that hold the same shape at
        that retraction, then rotation and retraction unchanged)."""
        return self._convert_tendon_part(q, self.displacements_for_tensions, validate)

    def configuration_to_tensions(self, q, *, validate: bool = True) -> np.ndarray:
        """The inverse of :meth:`configuration_to_displacements`: displacement form
        ``(..., n_config)`` to tension form (tensions solved at the configuration's retraction)."""
        return self._convert_tendon_part(q, self.tensions_for_displacements, validate)

    def _convert_tendon_part(self, q, convert, validate: bool) -> np.ndarray:
        """``q`` with its tendon part replaced by ``convert(part, retraction=..., validate=...)``
        at each configuration's own retraction; rotation and retraction unchanged."""
        q = np.array(q, dtype=np.float64)
        part, _, ret = self.split_configuration(q, validate=validate)
        out = q.copy()
        out[..., : self.n_tendons] = convert(part, retraction=ret, validate=validate)
        return out

    # ------------------------------------------------------------ base rotation/retraction
    def check_base_motion(self, rotation, retraction, batch_shape) -> tuple:
        """``(rotation, retraction)`` broadcast to ``batch_shape`` (``None`` stays ``None``),
        checked against the robot's :class:`BaseMotion` (enabled, within limits)."""
        bm = self.base_motion
        out = []
        for name, value, enabled, lim, unit in (
            ("rotation", rotation, bm.rotation, bm.rotation_limits, "rad"),
            ("retraction", retraction, bm.retraction, bm.retraction_limits, "m"),
        ):
            if value is None:
                out.append(None)
                continue
            if not enabled:
                raise InvalidInputError(
                    f"{name}: robot {self.name!r} has no base {name} (its file does not enable it)"
                )
            arr = as_array(value, name)
            try:
                arr = np.broadcast_to(arr, batch_shape)
            except ValueError:
                raise InvalidInputError(
                    f"{name}: expected a scalar or shape {batch_shape}, got {arr.shape}"
                ) from None
            check_range(arr, f"{name} [{unit}]", low=lim[0], high=lim[1])
            out.append(np.ascontiguousarray(arr, dtype=np.float64))
        return tuple(out)

    def retracted(self, retraction: float) -> TendonRobot:
        """The exposed part of this robot retracted by ``retraction`` [m], as a robot of its own.

        Length ``L - retraction``, routing polynomials shifted to the exposed arc length
        (:func:`shift_polynomial`), disks beyond the retraction kept (shifted), the same number
        of integration steps as the whole robot (so shapes of different retractions stack),
        identity base pose and no base motion. Cached per value.
        """
        rho = float(retraction)
        cache = self.__dict__.setdefault("_retracted", {})
        if rho in cache:
            return cache[rho]
        p = self.params
        bb = p.backbone
        L = bb.length - rho
        if rho == 0.0:
            sub_bb = bb
        else:
            sub_bb = replace(bb, length=L, step=L / bb.n_steps)
        tendons = tuple(
            replace(t, theta=shift_polynomial(t.theta, rho), radius=shift_polynomial(t.radius, rho))
            for t in p.tendons
        )
        kept = tuple(x - rho for x in p.disks.positions if x > rho)
        disks = Disks(len(kept), p.disks.radius, p.disks.thickness, p.disks.density, kept)
        sub = TendonRobot(
            replace(
                p,
                backbone=sub_bb,
                disks=disks,
                tendons=tendons,
                base=BasePose(),
                base_motion=BaseMotion(),
            )
        )
        if len(cache) >= 256:  # bounded: data sets draw many retractions
            cache.pop(next(iter(cache)))
        cache[rho] = sub
        return sub

    def _per_retraction(self, method: str, values, retraction, validate: bool) -> np.ndarray:
        """``method`` of :meth:`retracted` robots, grouped by retraction value."""
        by_disp = method == "tensions_for_displacements"
        check = self.check_displacements if by_disp else self.check_tensions
        arr = check(values) if validate else np.asarray(values, dtype=float)
        _, ret = self.check_base_motion(None, retraction, arr.shape[:-1])
        flat = arr.reshape(-1, self.n_tendons)
        rflat = ret.reshape(-1)
        out = np.empty_like(flat)
        for rho in np.unique(rflat):
            idx = np.flatnonzero(rflat == rho)
            out[idx] = getattr(self.retracted(rho), method)(flat[idx], validate=False)
        return out.reshape(arr.shape)

    def _solve_moved(self, by_tension: bool, values, rotation, retraction, validate) -> RodShape:
        """Shapes with base rotation and/or retraction (see :meth:`solve_tensions`)."""
        if self.loaded:
            raise InvalidInputError(
                "base rotation/retraction with gravity is not modelled (the exposed part's "
                "load would depend on the retracted part); switch gravity off"
            )
        check = self.check_tensions if by_tension else self.check_displacements
        arr = check(values) if validate else np.asarray(values, dtype=float)
        batch = arr.shape[:-1]
        rot, ret = self.check_base_motion(rotation, retraction, batch)
        flat = np.ascontiguousarray(arr.reshape(-1, self.n_tendons))
        B, n, m = flat.shape[0], self._n + 1, self.n_tendons
        rflat = np.zeros(B) if ret is None else ret.reshape(-1)
        P = np.empty((B, n, 3))
        Rs = np.empty((B, n, 3, 3))
        tau = np.empty((B, m))
        S = np.empty((B, n))
        for rho in np.unique(rflat):
            idx = np.flatnonzero(rflat == rho)
            sub = self.retracted(rho)
            solve = sub.solve_tensions if by_tension else sub.solve_displacements
            shape = solve(flat[idx], validate=False)
            P[idx], Rs[idx], tau[idx] = shape.positions, shape.rotations, shape.tensions
            S[idx] = shape.s
        if rot is not None:
            Rz = rotation_z(rot.reshape(-1))
            P = np.einsum("bij,bnj->bni", Rz, P)
            Rs = np.einsum("bij,bnjk->bnik", Rz, Rs)
        shape = self._to_world(P, Rs, tau, batch)
        # without retraction every row holds the whole robot's stations
        s = S.reshape(batch + (n,)) if (ret is not None and batch) else S[0].copy()
        s.flags.writeable = False
        return RodShape(s, shape.positions, shape.rotations, shape.tensions)

    def local_failure_error(self, tau) -> ConvergenceError:
        """The error for a failed local strain solve (eqs. 2-3) of the unloaded rod, naming the
        first node where a plain Newton re-solve stops and its scaled residual ``max |F_a / K_aa|``."""
        tau = np.ascontiguousarray(tau, dtype=np.float64)
        F, J, rhs, zero = np.empty(6), np.empty((6, 6)), np.empty((6, 1)), np.zeros(3)
        x = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
        kse, kbt = self.tables.kse, self.tables.kbt
        for k in range(self._n + 1):
            rt, drt = self.tables.offsets[2 * k], self.tables.offset_slopes[2 * k]
            if (
                cosserat.local_strains(
                    x, tau, rt, drt, zero, zero, kse, kbt, LOCAL_TOL, LOCAL_MAXIT, F, J, rhs
                )
                < 0
            ):
                res = float(cosserat.local_residual(x, tau, rt, drt, zero, zero, kse, kbt, F))
                return ConvergenceError(
                    f"local strain solve failed at s = {self._s[k]:.4g} m for tensions {tau.tolist()} "
                    f"(scaled residual {res:.3g} after {LOCAL_MAXIT} Newton iterations, tolerance {LOCAL_TOL:g})",
                    residual=res,
                    iterations=LOCAL_MAXIT,
                )
        return ConvergenceError(
            f"local strain solve failed for tensions {tau.tolist()} (a plain Newton re-solve converges)"
        )

    def _shoot(self, tau) -> np.ndarray:
        """States ``(n+1, 18+m)`` of the loaded rod: ``N(0) = f L`` exactly, ``M(0)`` by Newton."""
        m, n, L = self.n_tendons, self._n, self._L
        f = self._gravity_base()
        N0 = f * L
        Y = np.empty((n + 1, 18 + m))
        # start: base moment of the gravity load on the unloaded shape, M(0) = int p' x f (L - s) ds
        P = np.empty((n + 1, 3))
        Rs = np.empty((n + 1, 3, 3))
        X = np.empty((n + 1, 6))
        lengths = np.empty(m)
        if (
            cosserat.shape_free(tau, *self.tables, LOCAL_TOL, LOCAL_MAXIT, P, Rs, X, lengths)
            != cosserat.OK
        ):
            raise self.local_failure_error(tau)
        mid = 0.5 * (P[1:] + P[:-1])
        M0 = np.cross(mid - P[0], f).sum(0) * (L / n)
        scale = max(1e-6, float(np.linalg.norm(f)) * L * L)

        def residual(M):
            st = cosserat.shape_loaded(tau, *self.tables, f, N0, M, LOCAL_TOL, LOCAL_MAXIT, Y)
            if st != cosserat.OK:
                raise ConvergenceError(
                    f"local strain solve failed while shooting (tensions {tau.tolist()})"
                )
            return Y[-1, 15:18].copy()

        res = np.inf
        for _it in range(SHOOT_MAXIT):
            r = residual(M0)
            res = float(np.abs(r).max())
            if res <= SHOOT_TOL * max(1.0, scale * 1e3):
                return Y.copy()
            Jm = np.empty((3, 3))
            eps = 1e-6 * scale
            for j in range(3):
                Mp = M0.copy()
                Mp[j] += eps
                Jm[:, j] = (residual(Mp) - r) / eps
            M0 = M0 - np.linalg.solve(Jm, r)
        raise ConvergenceError(
            f"shooting did not converge in {SHOOT_MAXIT} iterations (tip moment residual {res:.3g} N m)",
            residual=res,
            iterations=SHOOT_MAXIT,
        )

    def solve_displacements(
        self, displacements, *, rotation=None, retraction=None, validate: bool = True
    ) -> RodShape:
        """Shape for tendon displacements ``(..., m)`` [m] (positive pulls the tendon in).

        ``rotation``/``retraction`` as in :meth:`solve_tensions`; displacements are then
        measured from the unloaded robot at the same retraction (the lab's
        ``calc_dl(home_shape(retraction).L_i, shape.L_i)``).

        Tensions solve the complementarity problem (compliant tendons, slack allowed)::

            g_i = l0_i - l_i(tau) + tau_i / k_i - d_i,  tau_i >= 0,  g_i >= 0,  tau_i g_i = 0

        (:func:`cosserat.solve_displacement_tensions`). ``RodShape.tensions`` holds them. Solved
        tensions above ``max_tension`` are returned with a logged warning (the limit bounds
        tension *input*). Raises :class:`ConvergenceError` with the residual on failure.

        Parameters
        ----------
        displacements : array_like
            ``(..., m)`` tendon displacements [m].
        rotation, retraction : float or array_like, optional
            As in :meth:`solve_tensions`.
        validate : bool
            Check the arguments.

        Returns
        -------
        RodShape
            Backbone of batch shape ``(...)``, with the solved ``tensions``.
        """
        if rotation is not None or retraction is not None:
            return self._solve_moved(False, displacements, rotation, retraction, validate)
        flat, batch = self._batch_input(displacements, self.check_displacements, validate)
        tau = self.tensions_for_displacements(flat, validate=False)
        over = tau > self._tmax * (1 + 1e-9)
        if np.any(over):
            log.warning(
                "displacements need tensions above max_tension in %d configuration(s)",
                int(np.any(over, -1).sum()),
            )
        shape = self.solve_tensions(tau, validate=False)
        n = self._n + 1
        return RodShape(
            shape.s,
            shape.positions.reshape(batch + (n, 3)),
            shape.rotations.reshape(batch + (n, 3, 3)),
            tau.reshape(batch + (self.n_tendons,)),
        )

    def tensions_for_displacements(
        self, displacements, *, retraction=None, validate: bool = True
    ) -> np.ndarray:
        """Tensions ``(..., m)`` [N] that realise tendon displacements ``(..., m)`` (see
        :meth:`solve_displacements`; with ``retraction`` [m], of the robot retracted by it)."""
        if retraction is not None:
            return self._per_retraction(
                "tensions_for_displacements", displacements, retraction, validate
            )
        flat, batch = self._batch_input(displacements, self.check_displacements, validate)
        B, m = flat.shape
        if self.loaded:
            tau = (
                np.stack([self._tensions_loaded(flat[b]) for b in range(B)])
                if B
                else np.zeros((0, m))
            )
            return tau.reshape(batch + (m,))
        # start: the linearisation at tau = 0 (see __init__), clipped to tau >= 0
        tau0 = np.ascontiguousarray(np.maximum(flat @ self._A0pinv.T, 0.0))
        tau = np.empty((B, m))
        infos = np.empty((B, 2))
        status = np.empty(B, dtype=np.int64)
        cosserat.solve_displacement_batch(
            flat,
            self._kinv,
            self._l0,
            tau0,
            *self.tables,
            LOCAL_TOL,
            LOCAL_MAXIT,
            DISP_TOL,
            DISP_MAXIT,
            tau,
            infos,
            status,
        )
        bad = np.flatnonzero(status != cosserat.OK)
        if bad.size:
            b = int(bad[0])
            raise ConvergenceError(
                f"tension solve for displacements {flat[b].tolist()} did not converge (residual {infos[b, 1]:.3g} m)",
                residual=float(infos[b, 1]),
                iterations=int(infos[b, 0]),
            )
        return tau.reshape(batch + (m,))

    def tendon_lengths(self, tensions, *, validate: bool = True) -> np.ndarray:
        """Tendon path lengths ``l_i = int |v + u x r_i + r_i'| ds`` ``(..., m)`` [m] for tensions ``(..., m)``.

        Parameters
        ----------
        tensions : array_like
            ``(..., m)`` [N].
        validate : bool
            Check the arguments.

        Returns
        -------
        numpy.ndarray
            ``(..., m)`` path lengths [m].
        """
        flat, batch = self._batch_input(tensions, self.check_tensions, validate)
        m = self.n_tendons
        out = np.empty(flat.shape)
        for b in range(flat.shape[0]):
            if self.loaded:
                out[b] = self._shoot(flat[b])[-1, 18:]
            else:
                dl = np.empty((m, m))
                if (
                    cosserat.lengths_and_jacobian(
                        flat[b], *self.tables, LOCAL_TOL, LOCAL_MAXIT, out[b], dl
                    )
                    != cosserat.OK
                ):
                    raise self.local_failure_error(flat[b])
        return out.reshape(batch + (m,))

    def displacements_for_tensions(
        self, tensions, *, retraction=None, validate: bool = True
    ) -> np.ndarray:
        """Actuator displacements ``d = l0 - l(tau) + tau / k`` ``(..., m)`` [m] that hold taut
        tendons at ``tensions`` (with ``retraction`` [m], of the robot retracted by it)."""
        if retraction is not None:
            return self._per_retraction(
                "displacements_for_tensions", tensions, retraction, validate
            )
        tau = self.check_tensions(tensions) if validate else np.asarray(tensions, dtype=float)
        return self._l0 - self.tendon_lengths(tau, validate=False) + tau * self._kinv

    def _tensions_loaded(self, d) -> np.ndarray:
        """Semismooth Newton on ``min(tau, g(tau)) = 0`` with finite differences (gravity on)."""
        m = self.n_tendons
        tau = np.maximum(self._A0pinv @ d, 0.0)

        def g(t):
            return self._l0 - self._shoot(t)[-1, 18:] + t * self._kinv - d

        res = np.inf
        for _it in range(DISP_MAXIT):
            gv = g(tau)
            act = tau > gv
            phi = np.where(act, gv, tau)
            res = float(np.abs(np.where(act, gv, tau * 1e-3)).max())
            if res <= 1e-11:
                return tau
            Jm = np.eye(m)
            for j in range(m):
                eps = 1e-6 * max(1.0, tau[j])
                tp = tau.copy()
                tp[j] += eps
                col = (g(tp) - gv) / eps
                Jm[act, j] = col[act]
            tau = np.maximum(tau - np.linalg.solve(Jm, phi), 0.0)
        raise ConvergenceError(
            f"tension solve with gravity did not converge (residual {res:.3g} m)",
            residual=res,
            iterations=DISP_MAXIT,
        )


def _robot_text(name_or_path) -> tuple[str, str]:
    key = str(name_or_path)
    if key in PACKAGED_ROBOTS:
        return resources.files("riskplan").joinpath("data", PACKAGED_ROBOTS[key]).read_text(
            encoding="utf-8"
        ), key
    p = Path(key)
    if not p.is_file():
        why = "it is a folder" if p.is_dir() else "no such file"
        raise RobotDescriptionError(
            f"robot: {key!r} is neither a packaged robot ({', '.join(PACKAGED_ROBOTS)}) "
            f"nor a TOML file ({why})",
            key="robot",
        )
    return read_robot_text(
        p
    ), p.stem  # RobotDescriptionError naming the file if unreadable or not UTF-8


def load_robot(name_or_path="paper") -> TendonRobot:
    """The one resolver of "name | path | robot".

    Parameters
    ----------
    name_or_path : str, os.PathLike or TendonRobot
        A packaged robot's name (``"paper"``), a robot TOML file, or a robot (returned as
        it is; so is an object with ``solve_displacements`` and ``toml_text``).

    Returns
    -------
    TendonRobot
        The robot.

    Raises
    ------
    RobotDescriptionError
        An unknown name, a missing or unreadable file, an invalid description.
    InvalidInputError
        Anything else.
    """
    if isinstance(name_or_path, TendonRobot) or (
        hasattr(name_or_path, "solve_displacements") and hasattr(name_or_path, "toml_text")
    ):
        return name_or_path
    if not isinstance(name_or_path, str | os.PathLike):
        raise InvalidInputError(
            f"robot: expected a TendonRobot or a robot name/path, got {type(name_or_path).__name__}"
        )
    text, default = _robot_text(name_or_path)
    return TendonRobot(parse_robot_toml(text, default_name=default), toml_text=text)


def robot_from_toml(text: str) -> TendonRobot:
    """Rebuild a robot from its TOML text (e.g. stored in a data set's metadata).

    Parameters
    ----------
    text : str
        The robot description.

    Returns
    -------
    TendonRobot
        A new robot.
    """
    return TendonRobot(parse_robot_toml(text), toml_text=text)


@functools.lru_cache(maxsize=8)
def cached_robot(text: str) -> TendonRobot:
    """The robot of a TOML text, built once per process (the one cache worker tasks that
    carry a robot as its text use: data generation, executions on the robot).

    Parameters
    ----------
    text : str
        The robot description.

    Returns
    -------
    TendonRobot
        The same object for the same text (at most 8 texts kept).
    """
    return robot_from_toml(text)
