"""The robots this installation knows, by name.

Every robot is a spec file (``regrasp.robot/1``, :mod:`planner.robot.spec_file`): the built-ins in
:mod:`robot_data` (``hrp5p``, the project's own generated model; ``jvrc1``, derived from the
``jvrc_description`` package; ``talos``, read from its installed package), then the files in the
folders of ``REGRASP_ROBOT_DIRS``. Unknown names get an error listing the valid ones.
"""

from __future__ import annotations

import hashlib
import os
from functools import lru_cache
from pathlib import Path

import robot_data
from planner.errors import UnknownRobotError
from planner.robot.spec import RobotSpec

DATA_DIR = robot_data.data_dir()
DEFAULT_ROBOT = "hrp5p"


ROBOT_DIRS_ENV = "REGRASP_ROBOT_DIRS"


def robot_dirs() -> list[Path]:
    """Configured folders of robot spec files (``REGRASP_ROBOT_DIRS``, separated like PATH)."""
    return [Path(p).expanduser() for p in os.environ.get(ROBOT_DIRS_ENV, "").split(os.pathsep) if p]


def _registered_spec_files() -> dict[str, Path]:
    """name -> spec file of every ``regrasp.robot/1`` file in the configured folders (first folder wins)."""
    out: dict[str, Path] = {}
    for folder in robot_dirs():
        for path in sorted([*folder.glob("*.yaml"), *folder.glob("*.yml")]):
            out.setdefault(path.stem, path)
    return out


def robot_names() -> list[str]:
    return sorted({p.stem for p in DATA_DIR.glob("*.yaml")} | set(_registered_spec_files()))


def _derived(ref: str):
    """The derived robot of a spec file path (``regrasp.robot/1``)."""
    from planner.robot.spec_file import derive

    return derive(ref)


def _spec_path(name: str) -> Path:
    path = DATA_DIR / f"{name}.yaml"
    if not path.is_file():
        raise UnknownRobotError(f"unknown robot {name!r}; valid robots: {', '.join(robot_names())}")
    return path


@lru_cache(maxsize=64)
def load_spec(name: str) -> RobotSpec:
    """A registered robot's spec by name, or a spec file's by its path (every robot is a ``regrasp.robot/1`` file)."""
    from planner.robot.spec_file import is_spec_path

    if is_spec_path(name):
        return _derived(name).spec
    if not (DATA_DIR / f"{name}.yaml").is_file() and name in _registered_spec_files():
        return _derived(str(_registered_spec_files()[name])).spec
    spec = _derived(str(_spec_path(name))).spec
    if spec.name != name:
        raise ValueError(f"robot spec file {name}.yaml names itself {spec.name!r}")
    return spec


def urdf_path(name: str) -> Path:
    """Absolute path of the URDF the robot is planned with: its own, or the derived one in the cache folder."""
    spec = load_spec(name)
    path = Path(spec.urdf)
    if not path.is_file():
        raise FileNotFoundError(f"URDF of robot {name!r} is missing at {path}; reinstall the package")
    return path


@lru_cache(maxsize=64)
def urdf_sha256(name: str) -> str:
    return hashlib.sha256(urdf_path(name).read_bytes()).hexdigest()
