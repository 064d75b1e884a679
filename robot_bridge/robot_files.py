"""Find a robot's URDF and spec file as DATA, without importing the planner.

The safety gate is an independent channel: it reads the same files the planner
ships (``NAME.urdf`` and ``NAME.yaml`` in the data-only package :mod:`robot_data`)
but never runs the planner's code, so ``planner`` never enters ``sys.modules``.
"""

from __future__ import annotations

import hashlib
import os
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
        """Acceleration limit (rad/s^2, m/s^2 for prismatic jaws) by the joint's group in the spec (per joint,
        with a default, in a ``regrasp.robot/1`` spec file)."""
        acc = self.spec["acceleration_limits"]
        if self.spec.get("schema") == ROBOT_SCHEMA:
            return float(acc.get(joint, acc.get("default", min(acc.values()))))
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


ROBOT_SCHEMA = "regrasp.robot/1"


def _spec_file(name: str) -> Path | None:
    """``NAME.yaml`` in the shipped robot data, else in the folders of ``REGRASP_ROBOT_DIRS``."""
    folders = [robot_data_dir()] + [Path(p).expanduser() for p in os.environ.get("REGRASP_ROBOT_DIRS", "").split(os.pathsep) if p]
    for folder in folders:
        for suffix in (".yaml", ".yml"):
            if (folder / f"{name}{suffix}").is_file():
                return folder / f"{name}{suffix}"
    return None


def _derived_urdf(name: str) -> Path:
    """The derived URDF of a spec-file robot, as the planner wrote it to the cache folder (the newest one; the
    gate compares its SHA-256 with the plan's before it trusts it)."""
    env = os.environ.get("REGRASP_CACHE_DIR")
    cache = (Path(env).expanduser() if env else Path("~/.cache/hrp-regrasp").expanduser()) / "robots"
    found = sorted(cache.glob(f"{name}-*/{name}.urdf"), key=lambda p: p.stat().st_mtime)
    if not found:
        raise RobotFilesError(f"robot {name!r} has no derived URDF in {cache}; run `regrasp robot check` on its spec "
                              "file once")
    return found[-1]


def robot_files(name: str) -> RobotFiles:
    """The files of robot ``name``; an unknown name lists the valid ones."""
    spec_path = _spec_file(name)
    if spec_path is None:
        raise RobotFilesError(f"unknown robot {name!r}; valid robots: {', '.join(robot_names())}")
    return _robot_files(str(spec_path), name)


@lru_cache(maxsize=None)
def _robot_files(spec_file: str, name: str) -> RobotFiles:
    data = robot_data_dir()
    spec_path = Path(spec_file)
    try:
        spec = yaml.safe_load(spec_path.read_text())
    except yaml.YAMLError as exc:
        raise RobotFilesError(f"robot spec {spec_path} is not valid YAML: {exc}") from exc
    if isinstance(spec, dict) and spec.get("schema") == ROBOT_SCHEMA:
        if "acceleration_limits" not in spec or not spec.get("hands"):
            raise RobotFilesError(f"robot spec {spec_path} lacks 'acceleration_limits' or 'hands'")
        return RobotFiles(name=name, urdf=_derived_urdf(name), spec=spec)
    if not isinstance(spec, dict) or "urdf" not in spec or "acceleration_limits" not in spec:
        raise RobotFilesError(f"robot spec {spec_path} lacks 'urdf' or 'acceleration_limits'")
    missing = [g for g in _ACC_GROUPS if g not in spec["acceleration_limits"]]
    if missing:
        raise RobotFilesError(f"robot spec {spec_path}: acceleration_limits lacks {missing}")
    urdf = (data / spec["urdf"]).resolve()
    if not urdf.is_file():
        raise RobotFilesError(f"URDF of robot {name!r} is missing at {urdf}; run `regrasp robot urdf {name}` once to generate it")
    return RobotFiles(name=name, urdf=urdf, spec=spec)
