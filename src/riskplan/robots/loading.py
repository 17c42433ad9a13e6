"""The one resolver of "name | path | robot" (:func:`load_robot`) and the per-process cache of
robots carried as their TOML text (:func:`cached_robot`)."""

from __future__ import annotations

import functools
import os
from importlib import resources
from pathlib import Path

from riskplan.errors import InvalidInputError, RobotDescriptionError
from riskplan.robots.description import parse_robot_toml, read_robot_text
from riskplan.robots.robot import TendonRobot

__all__ = ["PACKAGED_ROBOTS", "cached_robot", "load_robot", "robot_from_toml"]

#: packaged robots: name -> file in ``riskplan/data``
PACKAGED_ROBOTS = {"paper": "paper_robot.toml"}


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
