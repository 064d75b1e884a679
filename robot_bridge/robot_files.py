"""Find a robot's URDF and spec file as DATA, without importing the planner.

The safety gate is an independent channel: it reads the same files the planner
ships (``NAME.urdf`` and ``NAME.yaml`` in the data-only package :mod:`robot_data`)
but never runs the planner's code, so ``planner`` never enters ``sys.modules``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

import robot_data

#: Acceleration limit groups of the spec file.
_ACC_GROUPS = ("legs", "waist", "neck", "arms", "grippers")


class RobotFilesError(ValueError):
    """A robot's files are missing, unknown or malformed."""


def robot_data_dir() -> Path:
    """The directory holding ``*.urdf`` and ``*.yaml`` robot files."""
    path = robot_data.data_dir()
    if not path.is_dir():
        raise RobotFilesError(f"the robot data files are not installed (no directory {path})")
    return path


def robot_names() -> list[str]:
    return sorted(p.stem for p in robot_data_dir().glob("*.yaml"))


@dataclass(frozen=True)
class RobotFiles:
    """A robot's URDF path and the parts of its spec the gate needs."""

    name: str
    urdf: Path
    spec: dict[str, Any]

    @property
    def urdf_sha256(self) -> str:
        return hashlib.sha256(self.urdf.read_bytes()).hexdigest()

    def acceleration_limit(self, joint: str) -> float:
        """Acceleration limit (rad/s^2, m/s^2 for prismatic jaws) by the joint's group in the spec."""
        acc = self.spec["acceleration_limits"]
        feet = self.spec.get("feet", {})
        arms = self.spec.get("arms", {})
        if any(joint in foot.get("chain", []) for foot in feet.values()):
            return float(acc["legs"])
        if joint in self.spec.get("waist", []):
            return float(acc["waist"])
        if joint in self.spec.get("neck", []):
            return float(acc["neck"])
        for arm in arms.values():
            if joint == arm.get("gripper", {}).get("joint"):
                return float(acc["grippers"])
            if joint in arm.get("chain", []):
                return float(acc["arms"])
        return float(min(acc["legs"], acc["arms"]))


@lru_cache(maxsize=None)
def robot_files(name: str) -> RobotFiles:
    """The files of robot ``name``; an unknown name lists the valid ones."""
    data = robot_data_dir()
    spec_path = data / f"{name}.yaml"
    if not spec_path.is_file():
        raise RobotFilesError(f"unknown robot {name!r}; valid robots: {', '.join(robot_names())}")
    try:
        spec = yaml.safe_load(spec_path.read_text())
    except yaml.YAMLError as exc:
        raise RobotFilesError(f"robot spec {spec_path} is not valid YAML: {exc}") from exc
    if not isinstance(spec, dict) or "urdf" not in spec or "acceleration_limits" not in spec:
        raise RobotFilesError(f"robot spec {spec_path} lacks 'urdf' or 'acceleration_limits'")
    missing = [g for g in _ACC_GROUPS if g not in spec["acceleration_limits"]]
    if missing:
        raise RobotFilesError(f"robot spec {spec_path}: acceleration_limits lacks {missing}")
    urdf = (data / spec["urdf"]).resolve()
    if not urdf.is_file():
        raise RobotFilesError(f"URDF of robot {name!r} is missing at {urdf}; run `regrasp robot urdf {name}` once to generate it")
    return RobotFiles(name=name, urdf=urdf, spec=spec)
