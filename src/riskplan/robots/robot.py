"""``TendonRobot``: the validating facade over the Cosserat kernels (:mod:`riskplan.robots.cosserat`).

It caches the per-robot arrays (routing polynomials, stiffness diagonals, rest lengths),
checks inputs once at the boundary and places results in the world by the base pose.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from numba import njit

from riskplan._validation import as_array, check_range
from riskplan.errors import ConvergenceError, InvalidInputError
from riskplan.robots import actuation as _actuation
from riskplan.robots import cosserat
from riskplan.robots import loaded as _loaded
from riskplan.robots import motion as _motion
from riskplan.robots.params import BaseMotion, RobotParams, params_to_toml
from riskplan.robots.shape import RodShape
from riskplan.robots.tendon_lengths import rest_lengths_and_jacobian

__all__ = ["TendonRobot"]

log = logging.getLogger(__name__)


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


def _poly_table(polys) -> np.ndarray:
    K = max(len(c) for c in polys)
    out = np.zeros((len(polys), K))
    for i, c in enumerate(polys):
        out[i, : len(c)] = c
    return out


class TendonRobot:
    """A tendon-driven continuum robot described by :class:`RobotParams`.

    >>> from riskplan.robots import load_robot
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
        # rest lengths and their tension Jacobian: the length kernel's pass at tau = 0, in numpy
        # (the same numbers to the bit), so that building a robot compiles nothing
        self._l0, dl = rest_lengths_and_jacobian(*self.tables)
        if not (np.isfinite(self._l0).all() and np.isfinite(dl).all()):
            raise ConvergenceError("rest-length computation failed: non-finite tendon lengths")
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
        return _motion.configuration_limits(self)

    def split_configuration(self, q, *, validate: bool = True):
        """The parts of configurations in the lab's order (tendons, rotation, retraction).

        Parameters
        ----------
        q : array_like, shape (..., n_config)
            Configurations.
        validate : bool
            Check ``q``.

        Returns
        -------
        tendons : numpy.ndarray, shape (..., m)
            The tendon part (tensions in N or displacements in m).
        rotation, retraction : numpy.ndarray, shape (...), or None
            Base rotation (rad) and retraction (m); None where the robot has none.
        """
        return _motion.split_configuration(self, q, validate)

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
        """The robot file that rebuilds this robot.

        Returns
        -------
        str
            TOML text: the text read, or the parameters written out.
        """
        return self._toml if self._toml is not None else params_to_toml(self.params)

    def __repr__(self) -> str:
        return f"TendonRobot(name={self.name!r}, tendons={self.n_tendons}, length={self._L})"

    def with_base_pose(
        self, position=(0.0, 0.0, 0.0), *, rotation=None, rpy=None, quaternion=None
    ) -> TendonRobot:
        """The same robot with another base pose (give at most one orientation).

        Parameters
        ----------
        position : array_like, shape (3,)
            Base position (m, world frame).
        rotation : array_like, shape (3, 3), optional
            Rotation matrix, base to world.
        rpy : array_like, shape (3,), optional
            Roll, pitch, yaw (rad).
        quaternion : array_like, shape (4,), optional
            Scalar first ``(w, x, y, z)``.

        Returns
        -------
        TendonRobot
        """
        return _motion.with_base_pose(
            self, position, rotation=rotation, rpy=rpy, quaternion=quaternion
        )

    def with_gravity(self, enabled: bool = True, vector=None) -> TendonRobot:
        """The same robot with gravity switched on or off.

        Parameters
        ----------
        enabled : bool
        vector : array_like, shape (3,), optional
            Gravity in the world frame (m/s^2); default the robot's own.

        Returns
        -------
        TendonRobot
        """
        return _motion.with_gravity(self, enabled, vector)

    def interpolate_configurations(self, a, b, t) -> np.ndarray:
        """Points ``a + t (b - a)`` of the straight configuration-space motion from ``a`` to ``b``.

        A base rotation over a full turn takes the short way round and is wrapped into
        ``[-pi, pi)`` (the lab's ``VoxelEnvironment`` interpolation with
        ``util::canonical_angle``).

        Parameters
        ----------
        a, b : array_like, shape (..., n_config)
            The motion's ends.
        t : float or array_like, shape (...)
            Fractions in [0, 1].

        Returns
        -------
        numpy.ndarray, shape (..., n_config)
        """
        return _motion.interpolate_configurations(self, a, b, t)

    def configuration_to_displacements(self, q, *, validate: bool = True) -> np.ndarray:
        """A configuration in tension form in displacement form.

        Parameters
        ----------
        q : array_like, shape (..., n_config)
            Tensions (N), then rotation (rad) and retraction (m) where enabled.
        validate : bool
            Check ``q``.

        Returns
        -------
        numpy.ndarray, shape (..., n_config)
            Tendon displacements (m) that hold the same shape at that retraction, then
            rotation and retraction unchanged.
        """
        return _motion.configuration_to_displacements(self, q, validate=validate)

    def configuration_to_tensions(self, q, *, validate: bool = True) -> np.ndarray:
        """The inverse of :meth:`configuration_to_displacements`.

        Parameters
        ----------
        q : array_like, shape (..., n_config)
            Displacements (m), then rotation (rad) and retraction (m) where enabled.
        validate : bool
            Check ``q``.

        Returns
        -------
        numpy.ndarray, shape (..., n_config)
            Tensions (N) solved at the configuration's retraction, then rotation and
            retraction unchanged.
        """
        return _motion.configuration_to_tensions(self, q, validate=validate)

    def check_base_motion(self, rotation, retraction, batch_shape) -> tuple:
        """Base rotation and retraction checked against the robot's :class:`BaseMotion`
        (enabled, within limits).

        Parameters
        ----------
        rotation, retraction : float or array_like, optional
            Rotation (rad) and retraction (m), scalars or of ``batch_shape``; None for none.
        batch_shape : tuple of int
            The configurations' batch shape.

        Returns
        -------
        tuple
            ``(rotation, retraction)`` broadcast to ``batch_shape`` (None stays None).
        """
        return _motion.check_base_motion(self, rotation, retraction, batch_shape)

    def retracted(self, retraction: float) -> TendonRobot:
        """The exposed part of this robot retracted by ``retraction``, as a robot of its own.

        Length ``L - retraction``, routing polynomials shifted to the exposed arc length
        (:func:`shift_polynomial`), disks beyond the retraction kept (shifted), the same number
        of integration steps as the whole robot (so shapes of different retractions stack),
        identity base pose and no base motion. Cached per value.

        Parameters
        ----------
        retraction : float
            Retraction (m) within the robot's retraction limits.

        Returns
        -------
        TendonRobot
        """
        return _motion.retracted(self, retraction)

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
            and value.flags.writeable
        ):
            # flat and writeable: one compiled signature (numba specialises on the number of
            # dimensions and on read-only arrays; a read-only input takes the numpy checks)
            if in_limits(value.reshape(-1), low, high):
                return value
        arr = as_array(value, name, min_ndim=1)
        if arr.shape[-1] != self.n_tendons:
            raise InvalidInputError(
                f"{name}: expected last dimension {self.n_tendons} (one per tendon), got shape {arr.shape}"
            )
        check_range(arr, name, low=low, high=high)
        return arr

    def check_tensions(self, tensions) -> np.ndarray:
        """Tensions checked (:class:`InvalidInputError` otherwise): finite, one per tendon, in
        ``[0, max_tension]``.

        Parameters
        ----------
        tensions : array_like, shape (..., m)
            Tensions (N).

        Returns
        -------
        numpy.ndarray, shape (..., m)
        """
        return self._check(tensions, "tensions", self._tlow, self._tmax)

    def check_displacements(self, displacements) -> np.ndarray:
        """Displacements checked (:class:`InvalidInputError` otherwise): finite, one per
        tendon, within the displacement limits.

        Parameters
        ----------
        displacements : array_like, shape (..., m)
            Displacements (m).

        Returns
        -------
        numpy.ndarray, shape (..., m)
        """
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

    def _batch_input(self, values, check, validate: bool):
        """``(flat, batch)``: ``values (..., m)``, checked by ``check`` when ``validate``, as a
        C-contiguous float array ``flat (B, m)``, and the leading shape ``batch``."""
        a = check(values) if validate else np.asarray(values, dtype=float)
        flat = np.ascontiguousarray(a.reshape(-1, self.n_tendons))
        if not flat.flags.writeable:  # a read-only array would compile the kernels once more
            flat = flat.copy()
        return flat, a.shape[:-1]

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
            return _motion.solve_moved(self, True, tensions, rotation, retraction, validate)
        tau = self.check_tensions(tensions) if validate else np.asarray(tensions, dtype=float)
        if tau.ndim == 1 and not self.loaded:
            tau = np.array(tau, dtype=np.float64)  # a copy: the shape owns it
            P, Rs = _actuation.solve_single_free(self, tau)
            return self._to_world(P, Rs, tau, ())
        batch = tau.shape[:-1]
        flat = np.array(
            tau.reshape(-1, self.n_tendons), dtype=np.float64, order="C"
        )  # a copy: the shape owns it
        P, Rs = _actuation.solve_batch(self, flat)
        return self._to_world(P, Rs, flat, batch)

    def local_failure_error(self, tau) -> ConvergenceError:
        """The error for a failed local strain solve (eqs. 2-3) of the unloaded rod.

        Parameters
        ----------
        tau : array_like, shape (m,)
            The tensions (N) whose solve failed.

        Returns
        -------
        ConvergenceError
            Naming the first node where a plain Newton re-solve stops and its scaled residual
            ``max |F_a / K_aa|``.
        """
        return _actuation.local_failure_error(self, tau)

    def _shoot(self, tau) -> np.ndarray:
        """States ``(n+1, 18+m)`` of the loaded rod: ``N(0) = f L`` exactly, ``M(0)`` by Newton."""
        return _loaded.shoot(self, tau)

    def solve_displacements(
        self, displacements, *, rotation=None, retraction=None, validate: bool = True
    ) -> RodShape:
        """Shape for tendon displacements ``(..., m)`` [m] (positive pulls the tendon in).

        ``rotation``/``retraction`` as in :meth:`solve_tensions`; displacements are then
        measured from the unloaded robot at the same retraction (the lab's
        ``calc_dl(home_shape(retraction).L_i, shape.L_i)``).

        Tensions solve the complementarity problem (compliant tendons, slack allowed)::

            g_i = l0_i - l_i(tau) + tau_i / k_i - d_i,  tau_i >= 0,  g_i >= 0,  tau_i g_i = 0

        (:func:`cosserat.solve_displacement_tensions`). ``RodShape.tensions`` holds them. Without
        gravity the shape is integrated from the strains that the solve's last tendon-length
        pass solved at every RK4 node, at the returned tensions (no second pass); it differs from
        :meth:`solve_tensions` at those tensions by the two RK4 passes' O(h^4) difference (solved
        instead of Hermite-interpolated midpoint strains): at most 2.8e-7 m in position and
        3.6e-6 in the frames over 441 configurations spanning the paper robot's displacement
        box, the size of :meth:`solve_tensions`' own change from 40 to 80 steps (2.2e-7 m).
        With gravity, :meth:`solve_tensions` at the solved tensions. Solved
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
            return _motion.solve_moved(self, False, displacements, rotation, retraction, validate)
        flat, batch = self._batch_input(displacements, self.check_displacements, validate)
        if self.loaded:
            tau = self.tensions_for_displacements(flat, validate=False)
            P, Rs = _actuation.solve_batch(self, tau)
        else:  # the tension solve's last length pass gives the shape too
            tau, P, Rs = _actuation.shapes_for_displacements(self, flat)
        over = tau > self._tmax * (1 + 1e-9)
        if np.any(over):
            log.warning(
                "displacements need tensions above max_tension in %d configuration(s)",
                int(np.any(over, -1).sum()),
            )
        return self._to_world(P, Rs, tau, batch)

    def tensions_for_displacements(
        self, displacements, *, retraction=None, validate: bool = True
    ) -> np.ndarray:
        """Tensions that realise tendon displacements (the complementarity problem of
        :meth:`solve_displacements`).

        Parameters
        ----------
        displacements : array_like, shape (..., m)
            Displacements (m).
        retraction : float or array_like, optional
            Retraction (m): of the robot retracted by it.
        validate : bool
            Check the arguments.

        Returns
        -------
        numpy.ndarray, shape (..., m)
            Tensions (N).
        """
        if retraction is not None:
            return _motion.per_retraction(
                self, "tensions_for_displacements", displacements, retraction, validate
            )
        flat, batch = self._batch_input(displacements, self.check_displacements, validate)
        tau = _actuation.tensions_for_displacements(self, flat)
        return tau.reshape(batch + (self.n_tendons,))

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
        return _actuation.tendon_lengths(self, flat).reshape(batch + (self.n_tendons,))

    def displacements_for_tensions(
        self, tensions, *, retraction=None, validate: bool = True
    ) -> np.ndarray:
        r"""Actuator displacements that hold taut tendons at ``tensions``:

        .. math:: d = l_0 - l(\tau) + \tau / k.

        Parameters
        ----------
        tensions : array_like, shape (..., m)
            Tensions (N).
        retraction : float or array_like, optional
            Retraction (m): of the robot retracted by it.
        validate : bool
            Check the arguments.

        Returns
        -------
        numpy.ndarray, shape (..., m)
            Displacements (m).
        """
        if retraction is not None:
            return _motion.per_retraction(
                self, "displacements_for_tensions", tensions, retraction, validate
            )
        tau = self.check_tensions(tensions) if validate else np.asarray(tensions, dtype=float)
        return self._l0 - self.tendon_lengths(tau, validate=False) + tau * self._kinv
