"""Plans out: the files a robot controller reads, and back.

Tendon robots (the chest planner and any plan in tendon-displacement space):
:func:`tendon_plan` makes a :class:`TendonPlan` (times, displacements, tensions, per-step risk)
and :func:`write_tendon_plan` writes it as

* ``<stem>.csv`` -- one row per configuration: ``step, time_s, d_<tendon> (m)...,
  [base_rotation_rad, base_retraction_m,] tension_<tendon> (N)..., risk``;
* ``<stem>.json`` -- the same columns as lists, with names, units and the trajectory risk;
* ``<stem>.joint_trajectory.yaml`` -- a ROS 2 ``trajectory_msgs/msg/JointTrajectory``:
  ``joint_names`` = tendon names, then ``base_rotation`` (rad, a revolute joint about the
  base's z axis) and ``base_retraction`` (m, a prismatic joint, positive pulls the robot back
  into its base) when the robot has them; ``positions`` = displacements (m), then rotation and
  retraction; ``effort`` = tensions (N), then 0 for each base joint (no effort is planned for
  them); ``time_from_start`` = ``{sec, nanosec}``; e.g. ``ros2 topic pub /joint_trajectory
  trajectory_msgs/msg/JointTrajectory "$(cat plan.joint_trajectory.yaml)"``.

:func:`read_tendon_plan` reads any of the three back (the YAML's times to the nanosecond).

Tissue plans (simulator RRT + LQG): :func:`write_tissue_plan` writes the nominal controls as
CSV (``step, time_s, u0.., x0.., risk``; no ``time_s`` for quasi-static scenarios; risk is
LQG-MP's per-step collision probability; with the nominal reduced state ``x*_t`` the control is applied
in) and the LQG gains in NPZ (``L (T, q, p)`` feedback ``u_t = u*_t + L_t (x̂_t - x*_t)``,
``K (T, p, n)`` Kalman gains, and ``A, B, M, H, N``); :func:`read_tissue_plan` reads them back.

Conventions (one place): times in seconds from the plan's start; a tendon configuration's
timing is not part of the planners' output, so ``t_0 = 0`` and each step takes the time the
fastest-moving tendon needs at ``tendon_speed``, ``t_i = t_{i-1} + max_j |d_ij - d_(i-1)j| /
v``; ranks are 1-based (1 = the selected plan) and candidate indices 0-based, in tables and
files alike; quaternions are scalar-first ``(w, x, y, z)`` unless written ``xyzw:`` (ROS
order), see :meth:`riskplan.robots.BasePose.parse`.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from riskplan.errors import DataFormatError, InvalidInputError

# default actuator speed for the time stamps (m/s): 5 mm/s moves the paper robot's whole
# displacement range (50 mm) in 10 s; an open choice, stated in every file written
TENDON_SPEED = 0.005
# base speeds of the time stamps, open choices of the same kind, stated in every file: a
# half turn in 10 s (rad/s), and 10 mm/s retraction, which moves the lab's 0.119 m retraction
# range in about 12 s (m/s)
ROTATION_SPEED = np.pi / 10
RETRACTION_SPEED = 0.01
YAML_SUFFIX = ".joint_trajectory.yaml"
#: ROS joint names of the base's degrees of freedom (after the tendons, in the lab's order)
BASE_ROTATION_JOINT = "base_rotation"
BASE_RETRACTION_JOINT = "base_retraction"


@dataclass(frozen=True)
class TendonPlan:
    """A tendon-robot plan ready for export.

    Attributes
    ----------
    times : (T,) seconds from the start, non-decreasing.
    displacements : (T, m) tendon displacements (m).
    tensions : (T, m) tendon tensions (N) that realise them on the robot model, or None when
        no robot model is known (a model stored without its robot description).
    risk : (T,) per-step risk (e.g. the eq. 9 collision bound of each configuration).
    tendon_names : m names (the ROS joint names).
    trajectory_risk : risk of the whole trajectory (e.g. the eq. 10 bound), or None.
    name : plan name (nominal, optimised, ...).
    tendon_speed : the speed the times were made with (m/s), or None when given.
    rotation : (T,) base rotation (rad) about the base's z axis, or None (robot without it).
    retraction : (T,) base retraction (m, positive pulls the robot into its base), or None.
    """

    times: np.ndarray
    displacements: np.ndarray
    tensions: np.ndarray
    risk: np.ndarray
    tendon_names: tuple
    trajectory_risk: float | None = None
    name: str = "plan"
    tendon_speed: float | None = None
    rotation: np.ndarray | None = None
    retraction: np.ndarray | None = None

    def __post_init__(self):
        t = np.asarray(self.times, dtype=np.float64)
        d = np.asarray(self.displacements, dtype=np.float64)
        tau = None if self.tensions is None else np.asarray(self.tensions, dtype=np.float64)
        r = np.asarray(self.risk, dtype=np.float64)
        rot = None if self.rotation is None else np.asarray(self.rotation, dtype=np.float64)
        ret = None if self.retraction is None else np.asarray(self.retraction, dtype=np.float64)
        if d.ndim != 2 or d.shape[0] < 1:
            raise InvalidInputError(f"displacements: expected (T, m), got shape {d.shape}")
        T, m = d.shape
        arrays = [("times", t), ("displacements", d), ("risk", r)]
        arrays += [] if tau is None else [("tensions", tau)]
        arrays += [] if rot is None else [("rotation", rot)]
        arrays += [] if ret is None else [("retraction", ret)]
        for key, a, shape in (
            ("times", t, (T,)),
            ("tensions", tau, (T, m)),
            ("risk", r, (T,)),
            ("rotation", rot, (T,)),
            ("retraction", ret, (T,)),
        ):
            if a is not None and a.shape != shape:
                raise InvalidInputError(f"{key}: expected shape {shape}, got {a.shape}")
        for key, a in arrays:
            if not np.all(np.isfinite(a)):
                raise InvalidInputError(f"{key}: contain NaN or inf")
        if np.any(np.diff(t) < 0):
            raise InvalidInputError("times: must not decrease")
        names = tuple(str(n) for n in self.tendon_names)
        if len(names) != m or len(set(names)) != m:
            raise InvalidInputError(f"tendon_names: expected {m} distinct names, got {names}")
        clash = {BASE_ROTATION_JOINT, BASE_RETRACTION_JOINT} & set(names)
        if clash:
            raise InvalidInputError(
                f"tendon_names: {sorted(clash)} is the ROS joint name of a base degree of freedom; "
                "rename the tendon"
            )
        for key, a in arrays:
            a.setflags(write=False)
            object.__setattr__(self, key, a)
        object.__setattr__(self, "tendon_names", names)


def plan_times(
    displacements,
    tendon_speed: float = TENDON_SPEED,
    *,
    rotation=None,
    retraction=None,
    rotation_speed: float = ROTATION_SPEED,
    retraction_speed: float = RETRACTION_SPEED,
) -> np.ndarray:
    """``(T,)`` times: ``t_0 = 0`` and each step the time of its slowest actuator,

    .. math:: t_i = t_{i-1} + \\max\\big(\\max_j |d_{ij} - d_{i-1,j}| / v,\\;
              |\\mathrm{wrap}(\\theta_i - \\theta_{i-1})| / \\omega,\\;
              |r_i - r_{i-1}| / v_r\\big)

    with the base terms only where ``rotation`` (rad, the short way round as the robot model
    interpolates) or ``retraction`` (m) ``(T,)`` is given.
    """
    for key, v, unit in (
        ("tendon_speed", tendon_speed, "m/s"),
        ("rotation_speed", rotation_speed, "rad/s"),
        ("retraction_speed", retraction_speed, "m/s"),
    ):
        if not (np.isfinite(v) and v > 0):
            raise InvalidInputError(f"{key}: expected a positive speed ({unit}), got {v!r}")
    d = np.asarray(displacements, dtype=np.float64)
    step = np.abs(np.diff(d, axis=0)).max(axis=1) / tendon_speed if len(d) > 1 else np.zeros(0)
    if rotation is not None and len(d) > 1:
        dth = np.diff(np.asarray(rotation, dtype=np.float64))
        step = np.maximum(step, np.abs((dth + np.pi) % (2 * np.pi) - np.pi) / rotation_speed)
    if retraction is not None and len(d) > 1:
        step = np.maximum(
            step, np.abs(np.diff(np.asarray(retraction, dtype=np.float64))) / retraction_speed
        )
    return np.concatenate([[0.0], np.cumsum(step)])


def tendon_plan(
    robot,
    displacements,
    risk,
    *,
    trajectory_risk: float | None = None,
    name: str = "plan",
    tendon_speed: float = TENDON_SPEED,
) -> TendonPlan:
    """A :class:`TendonPlan` of a trajectory for ``robot`` (tensions from the robot model,
    :meth:`TendonRobot.tensions_for_displacements`, at each configuration's retraction; times
    from :func:`plan_times`).

    ``displacements``: ``(T, m)`` tendon displacements, or ``(T, n_config)`` configurations of a
    robot with base rotation and/or retraction (tendons, then rotation, then retraction: the
    lab's order), whose base columns become the plan's ``rotation``/``retraction``.
    ``robot`` may be ``None`` (a model stored without its robot): no tensions, tendons named
    ``tendon0 .. tendon{m-1}``."""
    q = np.asarray(displacements, dtype=np.float64)
    rot = ret = None
    if robot is not None and q.ndim == 2 and q.shape[1] == robot.n_config > robot.n_tendons:
        d, rot, ret = robot.split_configuration(q)
    else:
        d = q
    tau = None
    if robot is not None:
        tau = (
            robot.tensions_for_displacements(d)
            if ret is None
            else robot.tensions_for_displacements(d, retraction=ret)
        )
    return TendonPlan(
        times=plan_times(d, tendon_speed, rotation=rot, retraction=ret),
        displacements=d,
        tensions=tau,
        risk=np.asarray(risk, dtype=np.float64),
        tendon_names=(
            tuple(f"tendon{j}" for j in range(d.shape[1]))
            if robot is None
            else tuple(t.name for t in robot.params.tendons)
        ),
        trajectory_risk=None if trajectory_risk is None else float(trajectory_risk),
        name=name,
        tendon_speed=float(tendon_speed),
        rotation=rot,
        retraction=ret,
    )


def _conventions(plan: TendonPlan) -> dict:
    return {
        "time": "s from the plan's start"
        + (
            f"; each step at tendon speed {plan.tendon_speed} m/s of the fastest-moving tendon"
            if plan.tendon_speed
            else ""
        ),
        "displacement": "m, positive pulls the tendon in",
        "tension": "N, from the robot model"
        if plan.tensions is not None
        else "unknown (no robot model)",
        "risk": "per-step collision bound (eq. 9); trajectory_risk: eq. 10",
        "frame": "tendon space; no Cartesian frame",
        **(
            {
                "base_rotation": f"rad about the base's z axis; ROS joint {BASE_ROTATION_JOINT!r}, "
                f"timed at {ROTATION_SPEED:.6g} rad/s"
            }
            if plan.rotation is not None
            else {}
        ),
        **(
            {
                "base_retraction": "m, positive pulls the robot into its base; ROS joint "
                f"{BASE_RETRACTION_JOINT!r}, timed at {RETRACTION_SPEED} m/s"
            }
            if plan.retraction is not None
            else {}
        ),
    }


def _base_columns(plan: TendonPlan) -> list[tuple[str, str, np.ndarray]]:
    """``(csv column, ROS joint, values)`` of the plan's base degrees of freedom, in order."""
    out = []
    if plan.rotation is not None:
        out.append(("base_rotation_rad", BASE_ROTATION_JOINT, plan.rotation))
    if plan.retraction is not None:
        out.append(("base_retraction_m", BASE_RETRACTION_JOINT, plan.retraction))
    return out


def tendon_plan_csv(plan: TendonPlan) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    tau = plan.tensions is not None
    base = _base_columns(plan)
    w.writerow(
        ["step", "time_s"]
        + [f"d_{n}" for n in plan.tendon_names]
        + [c for c, _, _ in base]
        + ([f"tension_{n}" for n in plan.tendon_names] if tau else [])
        + ["risk"]
    )
    for i in range(len(plan.times)):
        w.writerow(
            [i, repr(float(plan.times[i]))]
            + [repr(float(v)) for v in plan.displacements[i]]
            + [repr(float(v[i])) for _, _, v in base]
            + ([repr(float(v)) for v in plan.tensions[i]] if tau else [])
            + [repr(float(plan.risk[i]))]
        )
    return buf.getvalue()


def tendon_plan_json(plan: TendonPlan) -> dict:
    return {
        "name": plan.name,
        "tendon_names": list(plan.tendon_names),
        "trajectory_risk": plan.trajectory_risk,
        "tendon_speed_m_per_s": plan.tendon_speed,
        "time_s": plan.times.tolist(),
        "displacements_m": plan.displacements.tolist(),
        "tensions_n": None if plan.tensions is None else plan.tensions.tolist(),
        "base_rotation_rad": None if plan.rotation is None else plan.rotation.tolist(),
        "base_retraction_m": None if plan.retraction is None else plan.retraction.tolist(),
        "risk": plan.risk.tolist(),
        "conventions": _conventions(plan),
    }


def _ros_duration(t: float) -> tuple[int, int]:
    ns = round(t * 1e9)
    return ns // 1_000_000_000, ns % 1_000_000_000


def joint_trajectory_yaml(plan: TendonPlan, frame_id: str = "") -> str:
    """ROS 2 ``trajectory_msgs/msg/JointTrajectory`` as YAML (block style, floats in full).

    Joints: the tendons (positions = displacements, m; effort = tensions, N), then
    ``base_rotation`` (rad) and ``base_retraction`` (m) where the plan has them (effort 0: none
    is planned for the base)."""

    def flow(values):
        return "[" + ", ".join(repr(float(v)) for v in values) + "]"

    base = _base_columns(plan)
    joints = list(plan.tendon_names) + [j for _, j, _ in base]
    what = "tendon displacements (m)" + "".join(
        f", {j} ({'rad' if j == BASE_ROTATION_JOINT else 'm'})" for _, j, _ in base
    )
    lines = [
        f"# riskplan plan {plan.name!r}: positions = {what}; effort = tensions (N)"
        + (", 0 for the base joints" if base else ""),
        "header:",
        "  stamp: {sec: 0, nanosec: 0}",
        f"  frame_id: {json.dumps(frame_id)}",
        "joint_names: [" + ", ".join(json.dumps(n) for n in joints) + "]",
        "points:",
    ]
    for i in range(len(plan.times)):
        sec, nsec = _ros_duration(float(plan.times[i]))
        pos = list(plan.displacements[i]) + [v[i] for _, _, v in base]
        eff = list(plan.tensions[i]) + [0.0] * len(base) if plan.tensions is not None else None
        lines += [
            f"  - positions: {flow(pos)}",
            "    velocities: []",
            "    accelerations: []",
            f"    effort: {flow(eff) if eff is not None else '[]'}",
            f"    time_from_start: {{sec: {sec}, nanosec: {nsec}}}",
        ]
    return "\n".join(lines) + "\n"


def write_tendon_plan(plan: TendonPlan, out_dir, stem: str | None = None) -> dict:
    """Write ``<stem>.csv``, ``<stem>.json`` and ``<stem>.joint_trajectory.yaml`` into ``out_dir``
    (atomically); returns ``{kind: path}``. ``stem`` defaults to the plan's name."""
    from riskplan.io import write_json_atomic, write_text_atomic

    if not isinstance(plan, TendonPlan):
        raise InvalidInputError(f"plan: expected a TendonPlan, got {type(plan).__name__}")
    out = Path(out_dir)
    stem = stem or plan.name
    files = {
        "csv": out / f"{stem}.csv",
        "json": out / f"{stem}.json",
        "ros": out / f"{stem}{YAML_SUFFIX}",
    }
    write_text_atomic(files["csv"], tendon_plan_csv(plan))
    write_json_atomic(files["json"], tendon_plan_json(plan))
    write_text_atomic(files["ros"], joint_trajectory_yaml(plan))
    return files


def read_tendon_plan(path) -> TendonPlan:
    """Read a plan written by :func:`write_tendon_plan` (``.csv``, ``.json`` or the ROS YAML)."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"plan file not found: {path}")
    try:
        if path.name.endswith((".yaml", ".yml")):
            return _read_yaml(path)
        if path.suffix == ".json":
            j = json.loads(path.read_text(encoding="utf-8"))
            return TendonPlan(
                times=j["time_s"],
                displacements=j["displacements_m"],
                tensions=j["tensions_n"],
                risk=j["risk"],
                tendon_names=j["tendon_names"],
                trajectory_risk=j.get("trajectory_risk"),
                name=j.get("name", path.stem),
                tendon_speed=j.get("tendon_speed_m_per_s"),
                rotation=j.get("base_rotation_rad"),
                retraction=j.get("base_retraction_m"),
            )
        if path.suffix == ".csv":
            return _read_csv(path)
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as exc:
        if isinstance(exc, InvalidInputError):
            raise DataFormatError(f"{path}: {exc}") from exc
        raise DataFormatError(f"{path}: not a riskplan plan file ({exc!r})") from exc
    raise InvalidInputError(f"{path}: expected a .csv, .json or {YAML_SUFFIX} plan file")


def _read_csv(path: Path) -> TendonPlan:
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], np.array(rows[1:], dtype=np.float64)
    names = [h[2:] for h in header if h.startswith("d_")]
    m = len(names)
    tau = any(h.startswith("tension_") for h in header)
    base = [h for h in header[2 + m :] if h in ("base_rotation_rad", "base_retraction_m")]
    nb = len(base)
    if (
        header[:2] != ["step", "time_s"]
        or header[-1] != "risk"
        or len(header) != 3 + (1 + tau) * m + nb
        or header[2 + m : 2 + m + nb] != base
    ):
        raise ValueError(f"unexpected columns {header}")
    body = body.reshape(-1, len(header))
    col = {h: body[:, 2 + m + k] for k, h in enumerate(base)}
    return TendonPlan(
        times=body[:, 1],
        displacements=body[:, 2 : 2 + m],
        tensions=body[:, 2 + m + nb : 2 + 2 * m + nb] if tau else None,
        risk=body[:, -1],
        tendon_names=names,
        name=path.stem,
        rotation=col.get("base_rotation_rad"),
        retraction=col.get("base_retraction_m"),
    )


def _read_yaml(path: Path) -> TendonPlan:
    import yaml

    msg = yaml.safe_load(path.read_text(encoding="utf-8"))
    pts = msg["points"]
    names = list(msg["joint_names"])
    times = [p["time_from_start"]["sec"] + p["time_from_start"]["nanosec"] * 1e-9 for p in pts]
    pos = np.array([p["positions"] for p in pts], dtype=np.float64).reshape(len(pts), len(names))
    tendon = [
        k for k, n in enumerate(names) if n not in (BASE_ROTATION_JOINT, BASE_RETRACTION_JOINT)
    ]
    base = {n: pos[:, k] for k, n in enumerate(names) if k not in tendon}
    eff = None
    if all(p["effort"] for p in pts):
        eff = np.array([p["effort"] for p in pts], dtype=np.float64)[:, tendon]
    return TendonPlan(
        times=times,
        displacements=pos[:, tendon],
        tensions=eff,
        risk=np.zeros(len(pts)),  # a JointTrajectory has no field for risk
        tendon_names=[names[k] for k in tendon],
        name=path.name.removesuffix(YAML_SUFFIX),
        rotation=base.get(BASE_ROTATION_JOINT),
        retraction=base.get(BASE_RETRACTION_JOINT),
    )


# ------------------------------------------------------------------------------ tissue
def write_tissue_plan(
    out_dir, plan, controller, *, dt: float | None, risk=None, stem: str = "selected"
) -> dict:
    """Write a tissue plan's nominal controls as ``<stem>_controls.csv`` and its LQG gains as
    ``<stem>_gains.npz`` (see the module doc); returns ``{kind: path}``.

    ``plan``: :class:`~riskplan.control.plan.NominalPlan`; ``controller``: its LQG controller
    (``L``, ``K``, ``P`` and ``lin`` with ``A, B, M, H, N``); ``dt``: the simulator's time step
    (s), or ``None`` for a quasi-static scenario (its steps have no duration: no time column);
    ``risk (T,)``: per-step risk, written as a last column ``risk`` (LQG-MP: ``1 - p_free_steps``,
    the probability of a collision on arriving at step ``t + 1`` having been free until ``t``).
    """
    from riskplan.io import atomic_path, write_text_atomic

    if dt is not None and not (np.isfinite(dt) and dt > 0):
        raise InvalidInputError(f"dt: expected a positive time step (s), got {dt!r}")
    U = np.asarray(plan.controls, dtype=np.float64)
    X = np.asarray(plan.reduced, dtype=np.float64)
    T, q = U.shape
    p = X.shape[1]
    if risk is not None:
        risk = np.asarray(risk, dtype=np.float64)
        if risk.shape != (T,) or not np.all(np.isfinite(risk)):
            raise InvalidInputError(f"risk: expected {T} finite numbers, got shape {risk.shape}")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    timed = ["time_s"] if dt is not None else []
    risky = ["risk"] if risk is not None else []
    w.writerow(["step", *timed] + [f"u{j}" for j in range(q)] + [f"x{j}" for j in range(p)] + risky)
    for t in range(T):
        w.writerow(
            [t, *([repr(t * float(dt))] if dt is not None else [])]
            + [repr(float(v)) for v in U[t]]
            + [repr(float(v)) for v in X[t]]
            + ([repr(float(risk[t]))] if risk is not None else [])
        )
    out = Path(out_dir)
    files = {"controls": out / f"{stem}_controls.csv", "gains": out / f"{stem}_gains.npz"}
    write_text_atomic(files["controls"], buf.getvalue())
    lin = controller.lin
    arrays = {
        "L": controller.L,
        "K": controller.K,
        "P": controller.P,
        "A": lin.A,
        "B": lin.B,
        "M": lin.M,
        "H": lin.H,
        "N": lin.N,
        "controls": U,
        "reduced": X,
        "dt": np.float64(np.nan if dt is None else dt),
    }
    with atomic_path(files["gains"], suffix=".npz") as tmp:
        np.savez(tmp, **{k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()})
    return files


def read_tissue_plan(controls_csv, gains_npz=None) -> dict:
    """Read :func:`write_tissue_plan`'s files: ``{"time_s" (or None), "controls" (T, q),
    "reduced" (T, p), "risk" (T,) (or None)}`` from the CSV, plus every gain array of the NPZ
    when given."""
    path = Path(controls_csv)
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    body = np.array(rows[1:], dtype=np.float64).reshape(len(rows) - 1, len(header))
    q = sum(h.startswith("u") for h in header)
    p = sum(h.startswith("x") for h in header)
    k = 2 if "time_s" in header else 1
    out = {
        "time_s": body[:, 1] if k == 2 else None,
        "controls": body[:, k : k + q],
        "reduced": body[:, k + q : k + q + p],
        "risk": body[:, -1] if header[-1] == "risk" else None,
    }
    if gains_npz is not None:
        with np.load(gains_npz, allow_pickle=False) as z:
            out["gains"] = {k: z[k] for k in z.files}
    return out
