"""Find a robot's URDF and spec file as DATA, without importing the planner.

The safety gate is an independent channel: it reads the same files the planner
ships (``NAME.yaml`` spec files of the ``regrasp.robot/1`` format and their URDFs, in
the data-only package :mod:`robot_data` or the folders of ``REGRASP_ROBOT_DIRS``) but
never runs the planner's code, so ``planner`` never enters ``sys.modules``.

Which URDF: the spec's own when it already has what the spec names (every sole and
TCP frame, a box on each sole frame) and no mesh collision to be fitted, as the
built-ins ``hrp5p`` and ``jvrc1``; the planner then uses it as it is. Otherwise the
derived URDF the planner wrote to the cache folder. Either way the gate compares
the file's SHA-256 with the plan's before it trusts it.
"""

from __future__ import annotations

import hashlib
import os
import re
import site
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

import robot_data

from robot_bridge.errors import BridgeError

ROBOT_SCHEMA = "regrasp.robot/1"


class RobotFilesError(BridgeError, ValueError):
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
        """Acceleration limit (rad/s^2, m/s^2 for prismatic jaws): the joint's own in the spec, else its default."""
        acc = self.spec["acceleration_limits"]
        return float(acc.get(joint, acc.get("default", min(acc.values()))))


def _spec_file(name: str) -> Path | None:
    """``NAME.yaml`` in the shipped robot data, else in the folders of ``REGRASP_ROBOT_DIRS``."""
    folders = [robot_data_dir()] + [Path(p).expanduser() for p in os.environ.get("REGRASP_ROBOT_DIRS", "").split(os.pathsep) if p]
    for folder in folders:
        for suffix in (".yaml", ".yml"):
            if (folder / f"{name}{suffix}").is_file():
                return folder / f"{name}{suffix}"
    return None


def _derived_urdf(name: str, urdf_sha256: str | None) -> Path:
    """The derived URDF of a spec-file robot, as the planner wrote it to the cache folder: the one whose
    SHA-256 is ``urdf_sha256`` (a plan's), else the newest. Several can be there (one per spec and URDF
    content); the gate compares the SHA-256 with the plan's before it trusts the file either way."""
    env = os.environ.get("REGRASP_CACHE_DIR")
    cache = (Path(env).expanduser() if env else Path("~/.cache/hrp-regrasp").expanduser()) / "robots"
    found = sorted(cache.glob(f"{name}-*/{name}.urdf"), key=lambda p: p.stat().st_mtime)
    if not found:
        raise RobotFilesError(f"robot {name!r} has no derived URDF in {cache}; run `regrasp robot check` on its spec "
                              "file once")
    if urdf_sha256:
        for path in reversed(found):
            if hashlib.sha256(path.read_bytes()).hexdigest() == urdf_sha256:
                return path
    return found[-1]


def robot_files(name: str, urdf_sha256: str | None = None) -> RobotFiles:
    """The files of robot ``name`` (for a derived URDF, the one of SHA-256 ``urdf_sha256`` when it is there);
    an unknown name lists the valid ones."""
    spec_path = _spec_file(name)
    if spec_path is None:
        raise RobotFilesError(f"unknown robot {name!r}; valid robots: {', '.join(robot_names())}")
    return _robot_files(str(spec_path), name, urdf_sha256 or None)


def _own_urdf(ref: str, spec_dir: Path, packages: dict[str, str]) -> Path | None:
    """The URDF file a spec names (relative to the spec, absolute, or ``package://``), or None if not found."""
    m = re.match(r"^package://(/?)([^/]+)/(.*)$", ref)
    if not m:
        path = Path(ref).expanduser()
        path = path if path.is_absolute() else spec_dir / path
        return path.resolve() if path.is_file() else None
    pkg, rest = m.group(2), m.group(3)
    roots = [Path(packages[pkg]).expanduser() if Path(packages[pkg]).is_absolute() else spec_dir / packages[pkg]] \
        if pkg in packages else []
    roots += [Path(p) / pkg for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
    roots += [Path(p) / "cmeel.prefix" / "share" / pkg for p in site.getsitepackages()]
    return next(((root / rest).resolve() for root in roots if (root / rest).is_file()), None)


def _usable_as_is(urdf: Path, spec: dict[str, Any]) -> bool:
    """Whether the planner plans with this URDF unchanged: it has every frame the spec's feet and hands name, a
    collision box on each sole frame, and no mesh collision (which ``collision: auto`` replaces by boxes)."""
    try:
        root = ET.parse(urdf).getroot()
    except (OSError, ET.ParseError):
        return False
    links = {el.attrib.get("name"): el for el in root.findall("link")}
    for side in ("left", "right"):
        sole = links.get(spec["feet"][side]["frame"])
        if sole is None or sole.find("collision/geometry/box") is None:
            return False
        if spec["hands"][side]["frame"] not in links:
            return False
    return spec.get("collision", "auto") == "auto" and root.find("link/collision/geometry/mesh") is None


@lru_cache(maxsize=64)
def _robot_files(spec_file: str, name: str, urdf_sha256: str | None) -> RobotFiles:
    spec_path = Path(spec_file)
    try:
        spec = yaml.safe_load(spec_path.read_text())
    except yaml.YAMLError as exc:
        raise RobotFilesError(f"robot spec {spec_path} is not valid YAML: {exc}") from exc
    if not isinstance(spec, dict) or spec.get("schema") != ROBOT_SCHEMA:
        got = spec.get("schema") if isinstance(spec, dict) else None
        raise RobotFilesError(f"robot spec {spec_path}: schema {got!r}, expected {ROBOT_SCHEMA!r}")
    for key in ("urdf", "feet", "hands", "acceleration_limits"):
        if not spec.get(key):
            raise RobotFilesError(f"robot spec {spec_path} lacks {key!r}")
    try:
        own = _own_urdf(str(spec["urdf"]), spec_path.parent, spec.get("packages") or {})
        as_is = own is not None and _usable_as_is(own, spec)
    except (KeyError, TypeError, AttributeError) as exc:
        raise RobotFilesError(f"robot spec {spec_path}: malformed feet or hands ({exc})") from exc
    return RobotFiles(name=name, urdf=own if as_is else _derived_urdf(name, urdf_sha256), spec=spec)
