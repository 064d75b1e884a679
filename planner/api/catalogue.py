"""What a request can name: robots, built-in scenarios, stances and meshes, and the checks of those names."""

from __future__ import annotations

from planner.jobs.request_names import RequestNameError, check_request, registered_robots, registered_stances
from planner.robot.registry import DEFAULT_ROBOT, UnknownRobotError, load_spec, robot_names, urdf_path, urdf_sha256
from planner.robot.spec_file import is_spec_path
from planner.scene.meshes import UnknownMeshError, mesh_file, portable_dump, registered_meshes
from planner.scene.scenarios import (
    ScenarioError,
    builtin_names,
    check_scenario,
    load_builtin,
    load_scenario,
    resolve_scenario,
    with_overrides,
)
from planner.stability.stances import BUILTIN_STANCES, StanceError, builtin_stance, sole_size, solve_stance

__all__ = [
    "BUILTIN_STANCES", "DEFAULT_ROBOT", "RequestNameError", "ScenarioError", "StanceError", "UnknownMeshError",
    "UnknownRobotError", "builtin_names", "builtin_stance", "check_request", "check_scenario",
    "is_spec_path", "load_builtin", "load_scenario", "load_spec", "mesh_file", "portable_dump", "registered_meshes",
    "registered_robots", "registered_stances", "resolve_scenario", "robot_names", "sole_size", "solve_stance",
    "urdf_path", "urdf_sha256", "with_overrides",
]
