"""What a job ran with: code version, library versions, robot model hash."""

from __future__ import annotations

import importlib.metadata
import subprocess
from functools import lru_cache
from pathlib import Path
from typing import Any

#: Distributions whose versions decide a plan's numbers.
TRACKED_DISTRIBUTIONS = ("hrp-regrasp", "numpy", "scipy", "pin", "python-fcl", "trimesh", "shapely",
                         "networkx", "pydantic", "eclipse-zenoh", "mcap")
REPO_ROOT = Path(__file__).resolve().parent.parent


@lru_cache(maxsize=1)
def library_versions() -> dict[str, str]:
    out: dict[str, str] = {}
    for dist in TRACKED_DISTRIBUTIONS:
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            continue
    import platform

    out["python"] = platform.python_version()
    return out


@lru_cache(maxsize=1)
def code_version() -> str:
    """Package version plus the git commit when running from a checkout (``+dirty`` if modified)."""
    try:
        version = importlib.metadata.version("hrp-regrasp")
    except importlib.metadata.PackageNotFoundError:
        version = "0+unknown"
    try:
        commit = subprocess.run(["git", "-C", str(REPO_ROOT), "rev-parse", "--short=12", "HEAD"],
                                capture_output=True, text=True, timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO_ROOT), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5, check=True).stdout.strip()
        return f"{version}+g{commit}{'.dirty' if dirty else ''}"
    except (OSError, subprocess.SubprocessError):
        return version


@lru_cache(maxsize=16)
def robot_sha256(robot: str) -> str | None:
    from planner.api.catalogue import urdf_sha256

    try:
        return urdf_sha256(robot)
    except (FileNotFoundError, ValueError):  # unknown robot: the planner reports it with the job
        return None


def provenance(robot: str, seed: int | None) -> dict[str, Any]:
    return {"seed": seed, "code_version": code_version(), "robot": robot, "robot_sha256": robot_sha256(robot),
            "library_versions": library_versions()}
