"""Scenarios: loading built-ins and files, and checking them before any planning.

Built-in scenarios are YAML files in ``planner/scene/scenario_data/``. A scenario file
is validated by :class:`schemas.scenario.Scenario`; :func:`check_scenario` then
checks what the schema cannot: the robot exists, the stance solves, the
threshold fits in the support polygon.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from planner.errors import ScenarioError
from schemas.scenario import Scenario
from schemas.stance import StanceDef

DATA_DIR = Path(__file__).parent / "scenario_data"
#: Largest scenario file accepted (a scenario is a few KB; anything bigger is a mistake).
MAX_SCENARIO_BYTES = 1_000_000


def builtin_names() -> list[str]:
    return sorted(p.stem for p in DATA_DIR.glob("*.yaml"))


def _format_validation(exc: ValidationError, source: str) -> str:
    lines = [f"{source} is not a valid scenario:"]
    for err in exc.errors():
        where = ".".join(str(p) for p in err["loc"]) or "(top level)"
        lines.append(f"  {where}: {err['msg']}")
    return "\n".join(lines)


def parse_scenario(data: Any, source: str = "scenario", base_dir: Path | None = None) -> Scenario:
    """Validate a scenario document (already parsed from YAML/JSON)."""
    if not isinstance(data, dict):
        raise ScenarioError(f"{source} must be a mapping with the fields of regrasp.scenario/1, got {type(data).__name__}")
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(_format_validation(exc, source)) from None
    if base_dir is not None:  # a robot spec file named by a path relative to the scenario file
        from planner.robot.spec_file import is_spec_path

        if is_spec_path(scenario.robot) and not Path(scenario.robot).expanduser().is_absolute():
            scenario = scenario.model_copy(update={"robot": str((base_dir / scenario.robot).resolve())})
    from .meshes import UnknownMeshError, resolve_mesh

    try:
        resolve_mesh(scenario.object.mesh, base_dir)
    except UnknownMeshError as exc:
        raise ScenarioError(f"{source}: object.mesh: {exc}") from None
    return scenario


def load_scenario_file(path: str | Path) -> Scenario:
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise ScenarioError(f"cannot read scenario file {path}: {exc.strerror}") from None
    if size > MAX_SCENARIO_BYTES:
        raise ScenarioError(f"scenario file {path} is {size} bytes; the limit is {MAX_SCENARIO_BYTES}")
    text = path.read_text()
    try:
        data = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (yaml.YAMLError, json.JSONDecodeError) as exc:
        raise ScenarioError(f"scenario file {path} is malformed: {exc}") from None
    return parse_scenario(data, str(path), base_dir=path.parent)


def load_builtin(name: str) -> Scenario:
    path = DATA_DIR / f"{name}.yaml"
    if not path.is_file():
        raise ScenarioError(f"unknown scenario {name!r}; built-in scenarios: {', '.join(builtin_names()) or '(none)'}")
    return load_scenario_file(path)


def load_scenario(ref: str | Path | dict) -> Scenario:
    """A scenario from a built-in name, a file path, or an inline document."""
    if isinstance(ref, dict):
        return parse_scenario(ref, "inline scenario")
    ref_s = str(ref)
    if ref_s.endswith((".yaml", ".yml", ".json")) or Path(ref_s).is_file():
        return load_scenario_file(ref_s)
    return load_builtin(ref_s)


def with_overrides(
    scenario: Scenario,
    *,
    stance: str | StanceDef | None = None,
    threshold_m: float | None = None,
    hands: str | None = None,
    seed: int | None = None,
    states_per_configuration: int | None = None,
    time_limit_s: float | None = None,
    survey: dict[str, Any] | None = None,
    mass_kg: float | None = None,
    speed_scale: float | None = None,
) -> Scenario:
    """The scenario with request/CLI overrides applied and re-validated.

    ``survey`` overrides fields of the scenario's ``survey:`` (until, ci_half_width, seeds_min,
    seeds_max, states_per_seed, leg_cap_states); ``states_per_configuration`` is the older way to say
    ``until: states`` with that many states per seed."""
    data = scenario.model_dump(by_alias=True)
    if stance is not None:
        data["stance"] = stance.model_dump() if isinstance(stance, StanceDef) else stance
    if threshold_m is not None:
        data["threshold_m"] = threshold_m
    if hands is not None:
        data["hands"] = hands
    if seed is not None:
        data["seed"] = seed
    if speed_scale is not None:
        data["speed_scale"] = speed_scale
    if states_per_configuration is not None:
        survey = {**(survey or {}), "until": "states", "states_per_seed": states_per_configuration}
    if survey:
        merged = {**data["survey"], **{k: v for k, v in survey.items() if v is not None}}
        if merged.get("until") == "solved":
            merged["states_per_seed"] = None
        merged["states_per_configuration"] = None
        data["survey"] = merged
    if time_limit_s is not None:
        data["limits"]["time_s"] = time_limit_s
    if mass_kg is not None:
        data["object"]["mass_kg"] = mass_kg
    from .meshes import carry_mesh_source

    return carry_mesh_source(scenario, parse_scenario(data, f"scenario {scenario.name!r} with overrides"))


@dataclass
class CheckReport:
    scenario: Scenario
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def check_scenario(scenario: Scenario) -> CheckReport:
    """Checks beyond the schema: robot, stance, threshold against the polygon, object, start/goal on a table."""
    from planner.robot.model import load_robot
    from planner.robot.registry import UnknownRobotError
    from planner.stability.stances import StanceError, solve_stance

    report = CheckReport(scenario)
    try:
        robot = load_robot(scenario.robot)
    except UnknownRobotError as exc:
        report.problems.append(str(exc))
        return report
    try:
        stance = solve_stance(robot, scenario.stance)
    except (StanceError, ValueError) as exc:
        report.problems.append(str(exc))
        return report
    inradius = stance.polygon.inradius
    report.notes.append(
        f"stance {stance.name}: robot CoM margin {stance.margin * 1000:.1f} mm, polygon inradius {inradius * 1000:.1f} mm"
    )
    if scenario.threshold_m > inradius:
        report.problems.append(
            f"threshold {scenario.threshold_m * 1000:.1f} mm is larger than the support polygon's inradius "
            f"{inradius * 1000:.1f} mm in stance {stance.name!r}: no state can be stable"
        )
    from planner.scene.objects import (
        build_object,  # here: objects and placements build on this module's models
    )
    from planner.scene.placements import check_resting_pose

    try:
        obj = build_object(scenario.object)
    except ValueError as exc:
        report.problems.append(f"object: {exc}")
    if not report.problems:
        for label, pose in (("start_pose", scenario.start_pose), ("goal_pose", scenario.goal_pose)):
            try:
                check_resting_pose(obj, pose, scenario.tables)
            except ValueError as exc:
                report.problems.append(f"{label}: {exc}")
    return report


def resolve_scenario(ref: Any, **overrides: Any) -> Scenario:
    """The scenario named or given by ``ref`` with the overrides that are not None applied."""
    return with_overrides(load_scenario(ref), **{k: v for k, v in overrides.items() if v is not None})
