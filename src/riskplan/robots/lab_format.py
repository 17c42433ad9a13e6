"""The Kuntz lab's robot files, read unchanged (Kuntz-Lab/Tendon_Robot_Learning, BSD-3).

The lab (University of Utah; the MDN paper's authors) describes tendon robots for its C++
library (``tendon::TendonRobot::from_toml`` in Kuntz-Lab/interactive-rate-tendons) in two
layouts, and its planning problems (``[problem]``, ``[environment]``,
``[voxel_environment]``, read by :mod:`riskplan.planning.problem`) in the same files:

* top level: ``[backbone_specs]``, ``[tendon_robot]``, ``[[tendons]]`` (task files such as
  ``resources/collapse-segmentation/tasks/task-0001.toml``);
* nested: ``[robot]`` (with ``radius``), ``[robot.backbone_specs]``, ``[[robot.tendons]]``
  (``resources/tendon-effusion-config.toml``; problem keys ``start``, ``goal``,
  ``min_tension_change``, ``max_tension`` at the top level).

Key by key (docs/robots.md has the table with units): ``E`` -> ``youngs_modulus``, ``nu`` ->
``poisson_ratio``, ``length``, ``length_discretization`` -> ``step``, ``ro``/``ri`` ->
``outer_radius``/``inner_radius``; a tendon's ``C`` (angle polynomial, rad) -> ``theta = pi/2 - C``
(the lab measures the angle from the body y axis towards x, :func:`lab_angle_to_theta`),
``D`` (distance polynomial, m) -> ``radius``, ``[min_length, max_length]`` (length change
``home - current``, m, positive = pulled in) -> ``displacement_limits``, ``max_tension`` (N);
``tendon_robot.radius`` -> ``collision_radius``; ``enable_rotation`` / ``enable_retraction``
-> ``[base_motion]``. The lab's tendons are inextensible and its robots carry no separator
disks, so ``stiffness`` stays infinite and ``disks.count`` 0; hysteresis takes riskplan's
defaults (the lab's files have none).

Errors name the key as the lab's file spells it (``tendons[2].C``), with the closest known
key for an unknown one.
"""

from __future__ import annotations

import math

from riskplan.errors import RobotDescriptionError
from riskplan.robots.params import (
    PROBLEM_TABLES,
    RobotParams,
    parse_robot_document,
)
from riskplan.robots.toml_fields import check_unknown_keys

__all__ = [
    "BACKBONE_DEFAULTS",
    "TENDON_DEFAULTS",
    "is_lab_layout",
    "lab_angle_to_theta",
    "lab_robot_table",
    "parse_lab_document",
]

#: defaults of the lab's ``tendon::BackboneSpecs`` (used where a file leaves a key out)
BACKBONE_DEFAULTS = {"length_discretization": 0.005, "nu": 0.3, "ri": 0.0}
#: defaults of the lab's ``tendon::TendonSpecs`` (the nested layout's files leave the limits out)
TENDON_DEFAULTS = {"min_length": -0.015, "max_length": 0.035}

_BACKBONE_KEYS = {"E", "nu", "length", "length_discretization", "ro", "ri"}
_TENDON_KEYS = {"C", "D", "max_tension", "min_length", "max_length"}
_ROBOT_KEYS = {"radius", "enable_rotation", "enable_retraction"}
#: top-level keys of the nested layout's problem part (tendon-effusion-config.toml)
_NESTED_PROBLEM_KEYS = {
    "start",
    "goal",
    "min_tension_change",
    "max_tension",
    *(f"{end}_{var}" for end in ("start", "goal") for var in ("rotation", "retraction")),
    "min_rotation_change",
    "min_retraction_change",
}


def lab_angle_to_theta(c):
    """riskplan's routing angle polynomial from the lab's ``C``: ``theta(s) = pi/2 - C(s)``.

    The lab places tendon i at ``D(s) (sin C(s), cos C(s), 0)`` in the body frame
    (``tendon::get_r_info`` in Kuntz-Lab/interactive-rate-tendons), riskplan at
    ``r(s) (cos theta(s), sin theta(s), 0)``; ``(sin C, cos C) = (cos(pi/2 - C), sin(pi/2 - C))``.
    Coefficients ``[c0, c1, ...]`` become ``[pi/2 - c0, -c1, ...]``. A value that is not a list
    of numbers is passed through unchanged for the parser to refuse with the key's name.

    Parameters
    ----------
    c : list of float or object
        The lab's ``C`` polynomial coefficients [rad, rad/m, ...].

    Returns
    -------
    list of float or object
        riskplan's ``theta`` coefficients, or ``c`` unchanged when it is not a list of numbers.
    """
    if not isinstance(c, list) or not c:
        return c
    if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in c):
        return c
    return [math.pi / 2 - float(c[0])] + [-float(v) for v in c[1:]]


def is_lab_layout(doc: dict) -> bool:
    """True for a document in one of the lab's two layouts.

    Parameters
    ----------
    doc : dict
        A parsed TOML document.

    Returns
    -------
    bool
        Whether it has ``backbone_specs`` (top level or under ``[robot]``) or ``tendon_robot``.
    """
    return (
        "backbone_specs" in doc
        or "tendon_robot" in doc
        or (isinstance(doc.get("robot"), dict) and "backbone_specs" in doc["robot"])
    )


def lab_robot_table(doc: dict) -> tuple[dict, str]:
    """``(table, prefix)``: the table holding ``backbone_specs``/``tendons`` and the key prefix
    (``""`` for the top-level layout, ``"robot."`` for the nested one). Checks top-level keys.

    Parameters
    ----------
    doc : dict
        A parsed lab document.

    Returns
    -------
    table : dict
        The table holding ``backbone_specs`` and ``tendons``.
    prefix : str
        ``""`` or ``"robot."``.
    """
    if isinstance(doc.get("robot"), dict) and "backbone_specs" in doc["robot"]:
        check_unknown_keys(doc, {"robot"} | PROBLEM_TABLES | _NESTED_PROBLEM_KEYS, "")
        robot = doc["robot"]
        check_unknown_keys(robot, _ROBOT_KEYS | {"backbone_specs", "tendons"}, "robot")
        return robot, "robot."
    check_unknown_keys(doc, {"backbone_specs", "tendon_robot", "tendons"} | PROBLEM_TABLES, "")
    tr = doc.get("tendon_robot", {})
    if not isinstance(tr, dict):
        raise RobotDescriptionError(
            "robot description: 'tendon_robot' must be a table", key="tendon_robot"
        )
    check_unknown_keys(tr, _ROBOT_KEYS, "tendon_robot")
    merged = {**tr, "backbone_specs": doc.get("backbone_specs"), "tendons": doc.get("tendons")}
    return merged, ""


def parse_lab_document(doc: dict, *, default_name: str = "robot") -> RobotParams:
    """A :class:`RobotParams` from a parsed lab document (either layout).

    Parameters
    ----------
    doc : dict
        A parsed lab document.
    default_name : str
        The robot's name when the document gives none.

    Returns
    -------
    RobotParams
        The robot's parameters (SI units).
    """
    robot, prefix = lab_robot_table(doc)
    robot_path = "robot" if prefix else "tendon_robot"
    bb = robot.get("backbone_specs")
    if not isinstance(bb, dict):
        raise RobotDescriptionError(
            f"robot description: missing table '[{prefix}backbone_specs]'",
            key=f"{prefix}backbone_specs",
        )
    check_unknown_keys(bb, _BACKBONE_KEYS, f"{prefix}backbone_specs")
    bbd = {**BACKBONE_DEFAULTS, **bb}
    native_bb = {}
    rename = {}  # native key -> lab key, for error messages
    for lab, nat in (
        ("length", "length"),
        ("ro", "outer_radius"),
        ("ri", "inner_radius"),
        ("E", "youngs_modulus"),
        ("nu", "poisson_ratio"),
        ("length_discretization", "step"),
    ):
        rename[f"backbone.{nat}"] = f"{prefix}backbone_specs.{lab}"
        if lab in bbd:
            native_bb[nat] = bbd[lab]
    tl = robot.get("tendons")
    if not isinstance(tl, list) or not tl:
        raise RobotDescriptionError(
            f"robot description: at least one '[[{prefix}tendons]]' entry is required",
            key=f"{prefix}tendons",
        )
    tendons = []
    for i, t in enumerate(tl):
        path = f"{prefix}tendons[{i}]"
        if not isinstance(t, dict):
            raise RobotDescriptionError(f"robot description: '{path}' must be a table", key=path)
        check_unknown_keys(t, _TENDON_KEYS, path)
        td = {**TENDON_DEFAULTS, **t}
        nt = {"name": f"tendon-{i}"}
        for lab, nat in (("C", "theta"), ("D", "radius"), ("max_tension", "max_tension")):
            rename[f"tendons[{i}].{nat}"] = f"{path}.{lab}"
            if lab in td:
                nt[nat] = td[lab]
        if "theta" in nt:
            nt["theta"] = lab_angle_to_theta(nt["theta"])
        rename[f"tendons[{i}].displacement_limits"] = f"{path}.min_length"
        nt["displacement_limits"] = [td["min_length"], td["max_length"]]
        for lab in ("min_length", "max_length"):
            v = td[lab]
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise RobotDescriptionError(
                    f"robot description: '{path}.{lab}' must be a number, got {v!r}",
                    key=f"{path}.{lab}",
                )
        tendons.append(nt)
    motion = {}
    for lab, nat in (("enable_rotation", "rotation"), ("enable_retraction", "retraction")):
        rename[f"base_motion.{nat}"] = f"{robot_path}.{lab}"
        if lab in robot:
            motion[nat] = robot[lab]
    native = {"name": default_name, "backbone": native_bb, "tendons": tendons}
    if motion:
        native["base_motion"] = motion
    rename["collision_radius"] = f"{robot_path}.radius"
    if "radius" in robot:
        native["collision_radius"] = robot["radius"]
    try:
        return parse_robot_document(native, default_name=default_name)
    except RobotDescriptionError as exc:
        key = exc.key
        if key in rename:
            msg = str(exc).replace(f"'{key}'", f"'{rename[key]}'")
            for nat, lab in rename.items():  # other keys the message names (e.g. "< outer_radius")
                msg = msg.replace(nat.split(".")[-1] + " (", lab.split(".")[-1] + " (")
            raise RobotDescriptionError(msg, key=rename[key]) from None
        raise
