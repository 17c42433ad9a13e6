"""Tendon-driven continuum robots: Cosserat-rod statics, hysteresis, sensing (MDN paper, Secs. III-IV).

>>> from riskplan.robots import load_robot
>>> robot = load_robot("paper")
>>> robot.solve_displacements([0.01, 0.0, 0.0, 0.0]).tip.shape
(3,)
"""

from riskplan.robots.description import parse_robot_toml
from riskplan.robots.loading import PACKAGED_ROBOTS, cached_robot, load_robot, robot_from_toml
from riskplan.robots.params import (
    Backbone,
    Disks,
    Gravity,
    HysteresisParams,
    RobotParams,
    Tendon,
    params_to_toml,
)
from riskplan.robots.pose import BasePose
from riskplan.robots.robot import TendonRobot
from riskplan.robots.shape import RodShape

__all__ = [
    "PACKAGED_ROBOTS",
    "Backbone",
    "BasePose",
    "Disks",
    "Gravity",
    "HysteresisParams",
    "RobotParams",
    "RodShape",
    "Tendon",
    "TendonRobot",
    "cached_robot",
    "load_robot",
    "params_to_toml",
    "parse_robot_toml",
    "robot_from_toml",
]
