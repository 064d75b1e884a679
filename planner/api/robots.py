"""A robot's model and description: loading it, describing and checking it, deriving a spec file, warming up
its kernels."""

from __future__ import annotations

from planner.robot.info import robot_info
from planner.robot.model import RobotModel, load_robot
from planner.robot.spec_file import derive as derive_spec_file
from planner.scene.robot_report import robot_report
from planner.warmup import warm_up

__all__ = ["RobotModel", "derive_spec_file", "load_robot", "robot_info", "robot_report", "warm_up"]
