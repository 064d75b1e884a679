"""The robots this installation knows, by name.

``hrp5p`` is the project's own generated model; ``jvrc1`` is derived from the
``jvrc_description`` package. Unknown names get an error listing the valid ones.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path

import yaml

import robot_data
from planner.errors import UnknownRobotError
from planner.robot.spec import RobotSpec

DATA_DIR = robot_data.data_dir()
DEFAULT_ROBOT = "hrp5p"


def robot_names() -> list[str]:
    return sorted(p.stem for p in DATA_DIR.glob("*.yaml"))


def _spec_path(name: str) -> Path:
    path = DATA_DIR / f"{name}.yaml"
    if not path.is_file():
        raise UnknownRobotError(f"unknown robot {name!r}; valid robots: {', '.join(robot_names())}")
    return path


@lru_cache(maxsize=None)
def load_spec(name: str) -> RobotSpec:
    spec = RobotSpec.model_validate(yaml.safe_load(_spec_path(name).read_text()))
    if spec.name != name:
        raise ValueError(f"robot spec file {name}.yaml names itself {spec.name!r}")
    return spec


def urdf_path(name: str) -> Path:
    """Absolute path of the robot's URDF (generated on first use for derived models)."""
    spec = load_spec(name)
    path = (DATA_DIR / spec.urdf).resolve()
    if not path.is_file():
        raise FileNotFoundError(f"URDF of robot {name!r} is missing at {path}; reinstall the package")
    return path


@lru_cache(maxsize=None)
def urdf_sha256(name: str) -> str:
    return hashlib.sha256(urdf_path(name).read_bytes()).hexdigest()
