"""The data-collection protocol of the MDN paper (section III) and its presets.

For every *target* configuration (tendon displacements on a grid over the displacement
limits) we draw ``n_starts`` random *starting* configurations, move the robot along the
straight line in configuration space from start to target through the hysteresis model
(:mod:`riskplan.robots.hysteresis`), and capture a point cloud on arrival with two
depth cameras. The clouds of one target together form its ground-truth distribution.

Configurations
--------------
The configuration space is discretised by a regular grid of ``grid_levels`` values per
tendon, ``linspace(low_i, high_i, grid_levels)``, in lexicographic order. The paper gives
only the counts (2,277 training, 253 test), and 2,530 = 2 * 5 * 11 * 23 is not the size of
any sensible 4-D grid, so the ``paper`` preset takes the 8^4 = 4,096-point grid and draws,
with the fixed ``split_seed``, a random subset of 2,530 grid points, of which 2,277 go to the
training and 253 (10 %) to the test split. The split depends on ``split_seed`` only, never on
the generation seed, so the training and test files of one protocol never share a target.

Other robots
------------
The presets are written for the paper's 4-tendon robot. For any other robot,
:func:`protocol_for_robot` keeps a preset's budget of target configurations (``n_train``,
``n_test``, starts, points) and chooses the grid to fit: the fewest levels ``L >= 2`` with
``L^d >= levels^4`` points, ``d`` the robot's configuration size (tendons, plus base rotation
and retraction where the robot has them), so a 3-tendon robot gets a 16-level grid for
``paper`` (4,096 points) and 5 levels for ``small``. The grid's box is the robot's
configuration limits with each tendon's upper displacement clipped to the displacement at
which that tendon alone reaches ``max_tension`` (``Protocol.limits``): displacement limits
wider than the tension limits allow would fill the data set with arrivals the robot may not
reach. The paper robot's protocols are unchanged by both rules.

A robot with base retraction exposes less of itself the more it retracts, and a tendon of a
shorter robot shortens less at the same tension (the lab's 0.12 m robot: 26.7 mm at 3.5 N fully
exposed, 0.2 mm at 0.119 m retraction); with inextensible tendons a displacement beyond that
cannot be reached at any tension. Its presets therefore set ``scale_by_exposure``: each
configuration's tendon displacements are drawn in the box at zero retraction and mapped
linearly onto the box at its own retraction, ``d' = lo + (d - lo) (h(rho) - lo) / (h(0) - lo)``
with ``h(rho)`` the displacement at which the tendon alone carries ``max_tension`` at
retraction ``rho`` (:func:`scale_by_exposure`). A base rotation over a full turn is periodic:
the grid's rotation levels stop one step short of ``lo + 2 pi`` (and so do the starts). The play operator's effective displacement on
arrival is capped at ``h(rho)`` too (:func:`exposure_upper`): the play (0.5 mm by default) is
wider than the whole box near full retraction (0.2 mm), and an inextensible tendon cannot be
shortened without bound.

Starts
------
The paper does not say how many starts were drawn per target. We take 8 for ``paper``:
with 512 points per cloud that is 4,096 points per target, enough to describe a 5-component
3-D mixture (45 free parameters per target), and 20,240 clouds in all, which generate in
minutes on a laptop. Starts are uniform within the displacement limits.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from riskplan._validation import check_count
from riskplan.errors import InvalidInputError

SPLITS = ("train", "test")


def _default_cameras() -> tuple[dict, ...]:
    from riskplan.robots.cameras import default_cameras

    return tuple(c.to_dict() for c in default_cameras())


@dataclass(frozen=True)
class Protocol:
    """Everything that decides a data set apart from the robot and the seed.

    Attributes
    ----------
    name: preset name (or ``"custom"``).
    grid_levels: grid values per tendon.
    n_train, n_test: number of target configurations per split (a seeded subset of the grid).
    n_starts: random starting configurations per target (clouds per target, ``S``).
    n_points: points per cloud after downsampling (``P``).
    path_steps: samples of the straight start-to-target path fed to the hysteresis model.
    split_seed: seed of the grid subset and the train/test split.
    surface_spacing: distance between surface samples rendered by the cameras (m).
    cameras: camera parameters (``PinholeCamera.to_dict()``), base frame.
    limits: ``((low, high), ...)`` per configuration variable (tendon displacements [m], then
        rotation [rad] and retraction [m] where enabled) of the grid and the random starts;
        ``None``: the robot's configuration limits (left out of the JSON when ``None``, so
        protocols without it keep their JSON text).
    scale_by_exposure: map the tendon displacements of each configuration onto the box at its
        retraction (robots with base retraction; :func:`scale_by_exposure`; left out of the JSON
        when False).
    """

    name: str = "custom"
    grid_levels: int = 3
    n_train: int = 60
    n_test: int = 15
    n_starts: int = 4
    n_points: int = 512
    path_steps: int = 16
    split_seed: int = 0
    surface_spacing: float = 0.0005
    cameras: tuple = field(default_factory=_default_cameras)
    limits: tuple | None = None
    scale_by_exposure: bool = False

    def __post_init__(self):
        for name in ("grid_levels", "n_starts", "n_points", "path_steps"):
            low = 2 if name in ("grid_levels", "path_steps") else 1
            check_count(getattr(self, name), f"protocol.{name}", low)
        for name in ("n_train", "n_test"):
            check_count(getattr(self, name), f"protocol.{name}", 0)
        if not (np.isfinite(self.surface_spacing) and self.surface_spacing > 0):
            raise InvalidInputError(
                f"protocol.surface_spacing: expected a positive length, got {self.surface_spacing!r}"
            )
        if len(self.cameras) < 1:
            raise InvalidInputError("protocol.cameras: expected at least one camera")
        if self.limits is not None:
            lim = np.asarray(self.limits, dtype=np.float64)
            if lim.ndim != 2 or lim.shape[1] != 2 or not np.all(np.isfinite(lim)):
                raise InvalidInputError(
                    f"protocol.limits: expected [[low, high], ...] per configuration variable, got {self.limits!r}"
                )
            if np.any(lim[:, 1] < lim[:, 0]):
                raise InvalidInputError(f"protocol.limits: low > high in {lim.tolist()}")
            object.__setattr__(self, "limits", tuple(tuple(float(v) for v in r) for r in lim))

    def n_configs(self, split: str) -> int:
        """Number of target configurations of a split.

        Parameters
        ----------
        split : str
            ``"train"`` or ``"test"``.

        Returns
        -------
        int
            ``n_train`` or ``n_test``.
        """
        return {"train": self.n_train, "test": self.n_test}[_check_split(split)]

    def camera_objects(self):
        """The protocol's cameras as camera objects.

        Returns
        -------
        tuple of PinholeCamera
            One per entry of ``cameras``.
        """
        from riskplan.robots.cameras import PinholeCamera

        return tuple(PinholeCamera.from_dict(c) for c in self.cameras)

    def to_json(self) -> str:
        """The protocol as compact JSON (keys sorted; defaults that older files lack are left out).

        Returns
        -------
        str
        """
        d = asdict(self)
        d["cameras"] = [dict(c) for c in self.cameras]
        if not self.scale_by_exposure:
            del d["scale_by_exposure"]
        if self.limits is None:
            del d["limits"]
        else:
            d["limits"] = [list(r) for r in self.limits]
        return json.dumps(d, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> Protocol:
        """Inverse of :meth:`to_json`; unknown keys raise :class:`InvalidInputError` with a suggestion.

        Parameters
        ----------
        text : str
            A JSON object of protocol fields.

        Returns
        -------
        Protocol
        """
        try:
            d = json.loads(text)
        except (TypeError, json.JSONDecodeError) as exc:
            raise InvalidInputError(f"protocol: not valid JSON ({exc})") from exc
        if not isinstance(d, dict):
            raise InvalidInputError("protocol: expected a JSON object")
        unknown = set(d) - set(cls.__dataclass_fields__)
        if unknown:
            from riskplan.robots.params import suggest_key

            known = set(cls.__dataclass_fields__)
            raise InvalidInputError(
                "protocol: unknown keys "
                + ", ".join(f"'{k}'{suggest_key(k, known)}" for k in sorted(unknown))
            )
        if "cameras" in d:
            d["cameras"] = tuple(d["cameras"])
        return cls(**d)

    def example_json(self) -> str:
        """A compact JSON text of this protocol without the cameras (they default), for help texts.

        Returns
        -------
        str
        """
        d = json.loads(self.to_json())
        del d["cameras"]
        return json.dumps(d, sort_keys=False)

    def replace(self, **changes) -> Protocol:
        """A copy with some fields changed (validated again).

        Parameters
        ----------
        **changes
            Field values.

        Returns
        -------
        Protocol
        """
        return replace(self, **changes)


PRESETS: dict[str, Protocol] = {}


def _register_presets() -> None:
    # 'paper': the counts of MDN paper section III (2,277 train / 253 test), 8 starts per target.
    PRESETS["paper"] = Protocol(name="paper", grid_levels=8, n_train=2277, n_test=253, n_starts=8)
    # 'small': seconds of work, for tests and the demo: 3^4 = 81 grid points, 60 / 15 used.
    PRESETS["small"] = Protocol(name="small", grid_levels=3, n_train=60, n_test=15, n_starts=4)
    # 'tiny': a handful of clouds, for unit tests of storage and resumption.
    PRESETS["tiny"] = Protocol(
        name="tiny", grid_levels=2, n_train=6, n_test=2, n_starts=2, path_steps=4
    )


_register_presets()


def get_protocol(preset_or_protocol) -> Protocol:
    """A :class:`Protocol` from a preset name, a Protocol, or its JSON text.

    Parameters
    ----------
    preset_or_protocol : str or Protocol
        A name of ``PRESETS``, a protocol (returned as it is) or its JSON.

    Returns
    -------
    Protocol
    """
    if isinstance(preset_or_protocol, Protocol):
        return preset_or_protocol
    if isinstance(preset_or_protocol, str):
        if preset_or_protocol in PRESETS:
            return PRESETS[preset_or_protocol]
        if preset_or_protocol.lstrip().startswith("{"):
            return Protocol.from_json(preset_or_protocol)
    raise InvalidInputError(
        f"preset: expected one of {sorted(PRESETS)} or a Protocol, got {preset_or_protocol!r}"
    )


#: configuration size the presets were written for (the paper's 4-tendon robot)
PRESET_DIMENSIONS = 4


def grid_levels_for(levels: int, dimensions: int) -> int:
    """The fewest levels ``L >= 2`` with ``L^dimensions >= levels^PRESET_DIMENSIONS`` (integer
    arithmetic): a grid of at least as many points as the preset's 4-D one."""
    want = int(levels) ** PRESET_DIMENSIONS
    L = 2
    while L**dimensions < want:
        L += 1
    return L


def tension_feasible_limits(robot) -> np.ndarray:
    """``(n_config, 2)`` configuration limits with each tendon's upper displacement clipped to
    ``d_i(max_tension_i e_i)``: the displacement at which tendon ``i`` alone carries its
    ``max_tension`` (others slack, no retraction)."""
    lim = np.array(robot.configuration_limits, dtype=np.float64)
    m = robot.n_tendons
    d = robot.displacements_for_tensions(np.diag(robot.tension_limits))  # (m, m)
    lim[:m, 1] = np.minimum(lim[:m, 1], np.diag(d))
    lim[:m, 1] = np.maximum(lim[:m, 1], lim[:m, 0])
    return lim


def protocol_for_robot(preset_or_protocol, robot) -> Protocol:
    """The protocol a generation for ``robot`` uses.

    A preset *name* adapts to the robot (module docs, "Other robots"): same budget of
    configurations, grid levels chosen to fit the robot's configuration size, box clipped to
    the tension limits. A :class:`Protocol` or its JSON is taken as given (a custom protocol is
    the user's choice; :func:`target_configurations` checks it fits).
    """
    p = get_protocol(preset_or_protocol)
    if not (isinstance(preset_or_protocol, str) and preset_or_protocol in PRESETS):
        return p
    d = robot.n_config
    levels = p.grid_levels if d == PRESET_DIMENSIONS else grid_levels_for(p.grid_levels, d)
    lim = tension_feasible_limits(robot)
    bm = robot.base_motion
    if bm.rotation:
        # a full turn is periodic: -pi and pi are one angle, so the grid stops a step short
        row = robot.n_tendons
        lo, hi = lim[row]
        if hi - lo >= 2 * np.pi - 1e-9:
            lim[row, 1] = lo + 2 * np.pi * (levels - 1) / levels
    full = np.asarray(robot.configuration_limits, dtype=np.float64)
    limits = None if np.array_equal(lim, full) else tuple(map(tuple, lim.tolist()))
    scale = bool(robot.base_motion.retraction)
    if levels == p.grid_levels and limits is None and not scale:
        return p
    return p.replace(grid_levels=levels, limits=limits, scale_by_exposure=scale)


def scale_by_exposure(configs, robot, limits) -> np.ndarray:
    """Configurations ``(N, n_config)`` with their tendon displacements mapped onto the box at
    their own retraction (module docs, "Other robots"); unchanged for robots without retraction.

    ``d' = lo + (d - lo) (h(rho) - lo) / (h(0) - lo)``, ``h(rho) = min(high, d_i(max_tension_i
    e_i; rho))`` per tendon, ``lo``/``high`` the tendon rows of ``limits (n_config, 2)``.
    """
    q = np.array(configs, dtype=np.float64)
    if not robot.base_motion.retraction or q.size == 0:
        return q
    m = robot.n_tendons
    lim = np.asarray(limits, dtype=np.float64)
    lo, hi0 = lim[:m, 0], lim[:m, 1]
    width0 = np.where(hi0 > lo, hi0 - lo, 1.0)
    ret = q[:, -1]
    for rho in np.unique(ret):
        h = exposure_upper(robot, float(rho), limits)
        idx = ret == rho
        q[idx, :m] = lo + (q[idx, :m] - lo) * (h - lo) / width0
    return q


def exposure_upper(robot, retraction: float, limits) -> np.ndarray:
    """``(m,)`` ``h(rho) = max(low, min(high, d_i(max_tension_i e_i; rho)))``: the upper end of
    each tendon's displacement box at retraction ``rho`` (``limits (n_config, 2)``)."""
    m = robot.n_tendons
    lim = np.asarray(limits, dtype=np.float64)
    d = robot.retracted(float(retraction)).displacements_for_tensions(np.diag(robot.tension_limits))
    return np.maximum(lim[:m, 0], np.minimum(lim[:m, 1], np.diag(d)))


def protocol_limits(protocol: Protocol, robot) -> np.ndarray:
    """``(n_config, 2)`` box of the grid and the starts: ``protocol.limits`` or the robot's."""
    lim = np.asarray(
        protocol.limits if protocol.limits is not None else robot.configuration_limits,
        dtype=np.float64,
    )
    if lim.shape != (robot.n_config, 2):
        raise InvalidInputError(
            f"protocol.limits: {lim.shape[0]} rows for a robot with {robot.n_config} configuration variables"
        )
    return lim


def _check_split(split: str) -> str:
    if split not in SPLITS:
        raise InvalidInputError(f"split: expected one of {SPLITS}, got {split!r}")
    return split


def grid(limits, levels: int) -> np.ndarray:
    """All grid configurations: ``linspace(low_i, high_i, levels)`` per variable.

    Parameters
    ----------
    limits : array_like, (m, 2)
        ``[low, high]`` per configuration variable (m; rad for a rotation).
    levels : int
        Grid points per variable.

    Returns
    -------
    numpy.ndarray, (levels**m, m)
        Lexicographic order (last variable fastest).
    """
    lim = np.asarray(limits, dtype=np.float64)
    if lim.ndim != 2 or lim.shape[1] != 2 or np.any(lim[:, 1] < lim[:, 0]):
        raise InvalidInputError(
            f"limits: expected (m, 2) [low, high] with low <= high, got {lim.tolist()}"
        )
    axes = [np.linspace(lo, hi, levels) for lo, hi in lim]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in mesh], axis=-1)


def target_configurations(protocol: Protocol, limits, split: str) -> np.ndarray:
    """Target configurations of ``split``.

    A random subset (seed ``protocol.split_seed``) of ``n_train + n_test`` grid points: the
    first ``n_train`` of the permutation are the training split, the next ``n_test`` the test split.

    Parameters
    ----------
    protocol : Protocol
        Grid levels, split sizes and seed.
    limits : array_like, (m, 2)
        ``[low, high]`` per configuration variable.
    split : str
        ``"train"`` or ``"test"``.

    Returns
    -------
    numpy.ndarray, (C, m)
        Sorted in grid order.
    """
    _check_split(split)
    g = grid(limits, protocol.grid_levels)
    need = protocol.n_train + protocol.n_test
    if need > len(g):
        d = g.shape[1]
        L = 2
        while L**d < need:
            L += 1
        raise InvalidInputError(
            f"protocol: n_train + n_test = {need} exceeds the {len(g)} points of a "
            f"{protocol.grid_levels}-level grid in {d} dimensions; use grid_levels >= {L} "
            "(or a preset name, which adapts to the robot)"
        )
    perm = np.random.default_rng(protocol.split_seed).permutation(len(g))
    idx = perm[: protocol.n_train] if split == "train" else perm[protocol.n_train : need]
    return g[np.sort(idx)]


def random_starts(limits, n: int, rng) -> np.ndarray:
    """Starting configurations, uniform within ``limits``.

    Parameters
    ----------
    limits : array_like, (m, 2)
        ``[low, high]`` per configuration variable.
    n : int
        Number of starts.
    rng : numpy.random.Generator
        Source of the draws.

    Returns
    -------
    numpy.ndarray, (n, m)
    """
    lim = np.asarray(limits, dtype=np.float64)
    return lim[:, 0] + (lim[:, 1] - lim[:, 0]) * rng.random((n, lim.shape[0]))


def straight_path(start, target, steps: int) -> np.ndarray:
    """Points of the straight line ``d(t) = start + t (target - start)``, ``t in [0, 1]``.

    Parameters
    ----------
    start, target : array_like, (m,)
        End configurations.
    steps : int
        Number of points.

    Returns
    -------
    numpy.ndarray, (steps, m)
        The first row is ``start`` and the last exactly ``target``.
    """
    start = np.asarray(start, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    t = np.linspace(0.0, 1.0, steps)[:, None]
    path = start + t * (target - start)
    path[-1] = target
    return path
