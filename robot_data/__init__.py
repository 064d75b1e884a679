"""The robot files the project ships: each robot's URDF and spec file (YAML), with notes and licences.

Data only, no code: the planner (which builds its pinocchio model from these files and generates
the built-in URDFs into this folder) and the safety gate (which reads them with its own parser)
both find them here through the installed package, neither knowing the other's layout.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def data_dir() -> Path:
    """The folder holding ``NAME.urdf`` and ``NAME.yaml`` of every shipped robot."""
    return Path(str(resources.files(__name__)))
