"""Reading robot descriptions: a TOML file or text to :class:`~riskplan.robots.params.RobotParams`.

The one entry for robot files of either layout: the native one (docs/robots.md,
``riskplan.robots.params.parse_robot_document``) and the Kuntz lab's two layouts
(:mod:`riskplan.robots.lab_format`, which translates them into the native document). It sits
above both readers, so that neither imports the other's dispatcher.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from riskplan.errors import RobotDescriptionError
from riskplan.robots import lab_format
from riskplan.robots.params import RobotParams, parse_robot_document

__all__ = ["load_robot_params", "parse_robot_toml", "read_robot_text"]


def parse_robot_toml(text: str, *, default_name: str = "robot") -> RobotParams:
    """Parse and validate a robot TOML document (format: docs/robots.md).

    Raises :class:`RobotDescriptionError` naming the offending key.

    Parameters
    ----------
    text : str
        The TOML document.
    default_name : str
        The robot's name when the document gives none.

    Returns
    -------
    RobotParams
    """
    if not isinstance(text, str):
        raise RobotDescriptionError(
            f"robot description: expected TOML text (str), got {type(text).__name__}; decode bytes as UTF-8 first",
            key=None,
        )
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RobotDescriptionError(f"robot description: not valid TOML ({exc})", key=None) from exc
    if lab_format.is_lab_layout(doc):
        return lab_format.parse_lab_document(doc, default_name=default_name)
    return parse_robot_document(doc, default_name=default_name)


def read_robot_text(path: str | Path) -> str:
    """Text of the robot TOML file ``path``, decoded as UTF-8 (TOML files are UTF-8 by spec).

    Raises :class:`RobotDescriptionError` naming the file if it cannot be read or is not
    valid UTF-8.

    Parameters
    ----------
    path : str or pathlib.Path
        The robot TOML file.

    Returns
    -------
    str
        Its text.
    """
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise RobotDescriptionError(
            f"robot description: {str(p)!r} is not valid UTF-8 text (byte {exc.start}: {exc.reason})"
        ) from exc
    except OSError as exc:
        raise RobotDescriptionError(f"robot description: cannot read {str(p)!r} ({exc})") from exc


def load_robot_params(path: str | Path) -> tuple[RobotParams, str]:
    """Read a robot TOML file (UTF-8); returns ``(params, text)``.

    Parameters
    ----------
    path : str or pathlib.Path
        The robot TOML file; its stem names a robot whose document gives no name.

    Returns
    -------
    params : RobotParams
        The parsed, validated parameters (:func:`parse_robot_toml`).
    text : str
        The file's text.
    """
    p = Path(path)
    text = read_robot_text(p)
    return parse_robot_toml(text, default_name=p.stem), text
