"""Path-dependent tendon transmission: play (backlash) operator plus run-to-run variation.

Friction between a tendon and its channels makes the displacement that reaches the robot lag
the actuator: while the actuator pulls, the tendon end moves only once the friction band is
overcome, and while it releases, it stays until the band is crossed the other way. The
simplest model with this behaviour, and the one used here, is the *play operator* (backlash)
per tendon ``i`` with half-width ``b_i`` acting on the commanded displacement ``c_i(t)``::

    e_i(t) = min(max(e_i(t-1), c_i(t) - b_i), c_i(t) + b_i)          (play operator)
    d_i    = clip(e_i + o_i, low_i, high_i)                           (effective displacement)

``e`` is the internal state (the engaged tendon position). Approaching a target from below
ends at ``target - b``, from above at ``target + b``: the same command gives different shapes
depending on the previous configuration (MDN paper, Fig. 3). Retracing the same path from the
same state gives the same result (the operator is rate independent and deterministic).

Run-to-run variation: each run (one call of :meth:`HysteresisModel.move` with a generator)
draws ``b_i = play * max(0, 1 + play_variation * z_i)`` and a zero offset
``o_i ~ N(0, offset_std^2)`` (re-tensioning / calibration error), ``z_i ~ N(0, 1)``. Without
a generator the nominal ``b_i = play``, ``o_i = 0`` are used. Parameters come from the robot
file's ``[hysteresis]`` table; docs/robots.md reports the tip spread they produce.

A capstan model (tension decaying as ``exp(-mu * wrapped angle)``) was considered; for
displacement-controlled tendons its net effect on the delivered displacement at rest is a
direction-dependent lag, which the play band reproduces with one interpretable parameter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan._validation import as_array, as_generator, check_range
from riskplan.errors import InvalidInputError
from riskplan.robots.params import HysteresisParams

__all__ = [
    "HysteresisModel",
    "HysteresisState",
    "effective_displacements",
    "play_operator",
    "robot_after_path",
]


@dataclass(frozen=True)
class HysteresisState:
    """Internal state of the transmission: engaged tendon positions ``engaged (..., m)`` [m]."""

    engaged: np.ndarray


def play_operator(engaged, path, play) -> np.ndarray:
    """Play operator over a path: ``engaged (..., m)``, ``path (..., T, m)``, ``play (..., m)`` -> ``(..., m)``.

    ``e_t = min(max(e_{t-1}, c_t - b), c_t + b)`` for t = 1..T; returns ``e_T`` (a new array,
    also for an empty path).

    Parameters
    ----------
    engaged : array_like, shape (..., m)
        Engaged positions ``e_0`` [m].
    path : array_like, shape (..., T, m)
        Commanded displacements ``c_t`` [m].
    play : array_like, shape (..., m)
        Half-widths ``b`` of the play [m].

    Returns
    -------
    numpy.ndarray
        ``e_T``, shape ``(..., m)``.
    """
    e = np.array(engaged, dtype=np.float64)
    c = np.asarray(path, dtype=np.float64)
    b = np.asarray(play, dtype=np.float64)
    for t in range(c.shape[-2]):
        ct = c[..., t, :]
        e = np.minimum(np.maximum(e, ct - b), ct + b)
    return e


def _check_state(state, m: int) -> np.ndarray:
    """``state.engaged`` as a finite float64 array ``(..., m)``; raises :class:`InvalidInputError`."""
    if not isinstance(state, HysteresisState):
        raise InvalidInputError(f"state: expected a HysteresisState, got {type(state).__name__}")
    return as_array(state.engaged, "state.engaged", last_dim=m)


def _check_path(path) -> np.ndarray:
    """A commanded path ``(..., T, m)`` with at least one configuration (T >= 1)."""
    c = as_array(path, "path", min_ndim=2)
    if c.shape[-2] == 0:
        raise InvalidInputError(
            f"path: expected at least one configuration (T >= 1), got shape {c.shape}"
        )
    return c


class HysteresisModel:
    """Play-operator transmission of a :class:`~riskplan.robots.TendonRobot` (see module docs).

    >>> from riskplan.robots import load_robot
    >>> model = HysteresisModel(load_robot("paper"))
    >>> state = model.initial_state()
    >>> state, d = model.move(state, [[0.01, 0, 0, 0]])
    >>> round(float(d[0]), 4)   # approached from below: lags by the play
    0.0095
    """

    def __init__(self, robot, params: HysteresisParams | None = None):
        self.robot = robot
        self.params = params if params is not None else robot.params.hysteresis
        p = self.params
        for key in ("play", "play_variation", "offset_std"):
            v = getattr(p, key)
            if not np.isfinite(v) or v < 0:
                raise InvalidInputError(f"hysteresis.{key}: expected a finite value >= 0, got {v}")
        self._lim = robot.displacement_limits

    @property
    def n_tendons(self) -> int:
        return self.robot.n_tendons

    def initial_state(self, displacements=None) -> HysteresisState:
        """State at rest at ``displacements (..., m)`` (default zeros), with no lag.

        Parameters
        ----------
        displacements : array_like, shape (..., m), optional
            Rest displacements [m] within the robot's limits.

        Returns
        -------
        HysteresisState
            Engaged at those displacements.
        """
        m = self.n_tendons
        if displacements is None:
            return HysteresisState(np.zeros(m))
        d = as_array(displacements, "displacements", last_dim=m)
        check_range(d, "displacements", low=self._lim[:, 0], high=self._lim[:, 1])
        return HysteresisState(d.copy())

    def sample_run(self, rng, batch_shape=()) -> tuple[np.ndarray, np.ndarray]:
        """Per-run parameters ``(play (..., m), offset (..., m))`` drawn from ``rng`` (seed or Generator).

        Parameters
        ----------
        rng : int, numpy.random.Generator or None
            Seed or generator.
        batch_shape : tuple of int
            Runs to draw.

        Returns
        -------
        play : numpy.ndarray
            ``(..., m)`` play widths ``b max(0, 1 + v z)`` [m], ``z`` standard normal.
        offset : numpy.ndarray
            ``(..., m)`` zero offsets, normal with ``offset_std`` [m].
        """
        g = as_generator(rng)
        shp = tuple(batch_shape) + (self.n_tendons,)
        p = self.params
        z = g.standard_normal(shp)
        play = p.play * np.maximum(0.0, 1.0 + p.play_variation * z)
        offset = p.offset_std * g.standard_normal(shp)
        return play, offset

    def move(self, state: HysteresisState, path, rng=None) -> tuple[HysteresisState, np.ndarray]:
        """Drive the actuators along ``path (..., T, m)`` (commanded displacements) from ``state``.

        Returns ``(new_state, effective (..., m))`` where ``effective`` is the displacement the
        robot receives at the end of the path. With ``rng`` (seed or Generator) the run draws its
        own play and offset (:meth:`sample_run`); without, nominal values. ``state.engaged`` must
        be finite with last dimension ``m`` and a batch shape broadcasting with the path's; an
        empty path (T = 0) leaves the state where it is.

        Parameters
        ----------
        state : HysteresisState
            The engaged positions before the path.
        path : array_like, shape (..., T, m)
            Commanded displacements [m] within the robot's limits.
        rng : int, numpy.random.Generator or None
            Draws the run's play and offset; None: nominal.

        Returns
        -------
        state : HysteresisState
            The engaged positions after the path.
        effective : numpy.ndarray
            ``(..., m)`` displacements [m] the robot receives, clipped to its limits.
        """
        m = self.n_tendons
        engaged = _check_state(state, m)
        c = as_array(path, "path", min_ndim=2)
        if c.shape[-1] != m:
            raise InvalidInputError(f"path: expected shape (..., T, {m}), got {c.shape}")
        check_range(c, "path", low=self._lim[:, 0], high=self._lim[:, 1])
        try:
            batch = np.broadcast_shapes(c.shape[:-2], engaged.shape[:-1])
        except ValueError as exc:
            raise InvalidInputError(
                f"state.engaged: batch shape {engaged.shape[:-1]} does not broadcast with the path's {c.shape[:-2]}"
            ) from exc
        if rng is None:
            play = np.full(batch + (m,), self.params.play)
            offset = np.zeros(batch + (m,))
        else:
            play, offset = self.sample_run(rng, batch)
        e = play_operator(engaged, c, play)
        eff = np.clip(e + offset, self._lim[:, 0], self._lim[:, 1])
        return HysteresisState(e), eff

    def straight_line(
        self, starts, targets, rng=None, *, start_state: HysteresisState | None = None
    ):
        """Effective displacements after moving straight from ``starts (..., m)`` to ``targets (..., m)``.

        Each tendon's command is monotone along a straight line, so the play operator's end value
        is ``clip(e_start, target - b, target + b)`` exactly; ``e_start`` is ``start_state.engaged``
        (default: the start itself, reached without lag). Vectorised over the batch; returns
        ``(state, effective (..., m))`` like :meth:`move`.

        Parameters
        ----------
        starts, targets : array_like, shape (..., m)
            Commanded start and end displacements [m].
        rng : int, numpy.random.Generator or None
            As :meth:`move`.
        start_state : HysteresisState, optional
            Engaged positions at the start (default the start itself).

        Returns
        -------
        state : HysteresisState
            The engaged positions at the target.
        effective : numpy.ndarray
            ``(..., m)`` displacements [m] the robot receives.
        """
        m = self.n_tendons
        a = as_array(starts, "starts", last_dim=m)
        t = as_array(targets, "targets", last_dim=m)
        for arr, name in ((a, "starts"), (t, "targets")):
            check_range(arr, name, low=self._lim[:, 0], high=self._lim[:, 1])
        path = np.stack(np.broadcast_arrays(a, t), axis=-2)
        state = start_state if start_state is not None else HysteresisState(a)
        return self.move(state, path, rng)

    def shape_after(self, state: HysteresisState, path, rng=None):
        """``(new_state, RodShape)`` after driving along ``path (..., T, m)`` (see :meth:`move`).

        Parameters
        ----------
        state : HysteresisState
            The engaged positions before the path.
        path : array_like, shape (..., T, m)
            Commanded displacements [m].
        rng : int, numpy.random.Generator or None
            As :meth:`move`.

        Returns
        -------
        state : HysteresisState
            The engaged positions after the path.
        shape : RodShape
            The robot's shape at the effective displacements.
        """
        new, eff = self.move(state, path, rng)
        return new, self.robot.solve_displacements(eff)


def robot_after_path(
    robot,
    path,
    *,
    state: HysteresisState | None = None,
    seed=None,
    params: HysteresisParams | None = None,
):
    """Shape of ``robot`` after the commanded path ``(T, m)`` through the hysteresis model.

    ``state`` defaults to rest at the path's first point; ``seed`` (int/Generator/None) draws
    the run-to-run variation (None: nominal, deterministic). Returns a :class:`RodShape`.
    Raises :class:`InvalidInputError` for an empty path (T = 0).

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    path : array_like, shape (T, m)
        Commanded displacements [m].
    state : HysteresisState, optional
        Engaged positions before the path.
    seed : int, numpy.random.Generator or None
        Draws the run-to-run variation.
    params : HysteresisParams, optional
        The transmission's parameters (default the robot's, ``params.hysteresis``).

    Returns
    -------
    RodShape
        The shape at the effective displacements.
    """
    eff = effective_displacements(robot, path, state=state, seed=seed, params=params)
    return robot.solve_displacements(eff)


def effective_displacements(
    robot,
    path,
    *,
    state: HysteresisState | None = None,
    seed=None,
    params: HysteresisParams | None = None,
) -> np.ndarray:
    """Effective displacements ``(..., m)`` the robot receives after the commanded ``path (..., T, m)``.

    ``state`` defaults to rest at the path's first point (no lag); ``seed`` (int, SeedSequence,
    Generator or None) draws this run's play widths and zero offsets (None: nominal values).
    Feed the result to ``robot.solve_displacements``. Raises :class:`InvalidInputError` for an
    empty path (T = 0).

    Parameters
    ----------
    robot : TendonRobot
        The robot.
    path : array_like, shape (..., T, m)
        Commanded displacements [m].
    state : HysteresisState, optional
        Engaged positions before the path.
    seed : int, numpy.random.SeedSequence, numpy.random.Generator or None
        Draws the run's play widths and offsets.
    params : HysteresisParams, optional
        The transmission's parameters (default the robot's).

    Returns
    -------
    numpy.ndarray
        ``(..., m)`` effective displacements [m].
    """
    model = HysteresisModel(robot, params)
    c = _check_path(path)
    if state is None:
        state = model.initial_state(c[..., 0, :])
    rng = None if seed is None else as_generator(seed)
    return model.move(state, c, rng)[1]
