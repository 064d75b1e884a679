"""The scenario file (``schema: regrasp.scenario/1``, docs/contract.md section 2)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, PrivateAttr, model_validator

from .common import Finite, FiniteVector, HandsChoice, Pose7, StrictModel, Vec3
from .stance import StanceDef

SCENARIO_SCHEMA = "regrasp.scenario/1"
ObjectShape = Literal["box", "cylinder", "bar", "drill", "mesh"]


#: Longest list a scenario holds (tables, obstacles); a real scene has a handful.
MAX_BOXES = 64
#: Longest number list of a size field.
MAX_SIZE_NUMBERS = 8


class MeshSource(StrictModel):
    """An object mesh: a registered name (portable), or, in scenario files and not in service requests, a file
    (a relative path resolves against the scenario file)."""

    name: str | None = Field(None, min_length=1, max_length=128,
                             description="a registered mesh (planner.scene.meshes: carrier_nx, carrier_px, ...)")
    path: str | None = Field(None, max_length=4096,
                             description="STL or OBJ file; relative paths resolve against the scenario file")
    scale: Finite = Field(1.0, gt=0)
    #: The path as the scenario file wrote it, when ``path`` was resolved against the file's folder
    #: (never serialised: a dump shows what was written, see planner.scene.meshes.portable_mesh).
    _written: str | None = PrivateAttr(None)

    @model_validator(mode="after")
    def _name_or_path(self) -> "MeshSource":
        if self.name is None and self.path is None:
            raise ValueError("a mesh needs name: REGISTERED or path: FILE")
        return self

    @model_validator(mode="after")
    def _one_source(self) -> "MeshSource":
        if self.name is None and self.path is None:
            raise ValueError("a mesh needs name: REGISTERED or path: FILE")
        return self


class ObjectDef(StrictModel):
    name: str = "object"
    shape: ObjectShape
    size: FiniteVector | None = Field(
        None, max_length=MAX_SIZE_NUMBERS,
        description="box/bar: [x, y, z] m; cylinder: [radius, height] m; drill: [x, y, z] bounding box (optional)",
    )
    mesh: MeshSource | None = None
    mass_kg: Finite = Field(gt=0, le=100, description="total mass of the object, kg")
    com_local: Vec3 | None = Field(None, description="CoM in the object frame, m; a point mass places it; default: geometric centre")

    @model_validator(mode="after")
    def _check(self) -> "ObjectDef":
        if self.shape == "mesh":
            if self.mesh is None:
                raise ValueError("shape 'mesh' needs mesh: {name: REGISTERED} or {path: FILE, scale: 1.0}")
        elif self.mesh is not None:
            raise ValueError(f"'mesh' is only for shape 'mesh', not {self.shape!r}")
        expected = {"box": 3, "bar": 3, "cylinder": 2, "drill": 3}.get(self.shape)
        if self.shape in ("box", "bar", "cylinder") and self.size is None:
            raise ValueError(f"shape {self.shape!r} needs size ({expected} numbers)")
        if self.size is not None and expected is not None:
            if len(self.size) != expected:
                raise ValueError(f"size of a {self.shape} has {expected} numbers, got {len(self.size)}")
            if any(s <= 0 for s in self.size):
                raise ValueError(f"size must be positive, got {self.size}")
            if max(self.size) > 3.0:
                raise ValueError(f"size {self.size} is over 3 m: sizes are in metres")
        return self


class BoxDef(StrictModel):
    name: str
    pose: Pose7 = Field(description="box centre in the world")
    size: Vec3

    @model_validator(mode="after")
    def _positive(self) -> "BoxDef":
        if any(s <= 0 for s in self.size):
            raise ValueError(f"box {self.name!r}: size must be positive, got {self.size}")
        return self


class Limits(StrictModel):
    time_s: Finite | None = Field(None, gt=0, le=3600, description="the user's own time budget, s (none by default): when "
                                  "it ends a run, the result is TIMEOUT and says how far it got; seeded runs otherwise "
                                  "stop on max_iterations, so a seed decides the result, not the machine's load")
    max_iterations: int = Field(2000, ge=1, le=1_000_000)


class SurveySettings(StrictModel):
    """How long the survey explores (docs/contract.md section 4): seeds until every row's interval is tight
    (``until: solved``), or a fixed number of states per seed (``until: states``)."""

    until: Literal["solved", "states"] = Field("solved", description="solved: each seed explores until it reaches the "
                                               "goal or the leg cap; states: each seed counts states_per_seed states")
    ci_half_width: Finite = Field(0.02, gt=0, le=0.5, description="largest distance of the 95 % bounds from R")
    seeds_min: int = Field(10, ge=1, le=10_000)
    seeds_max: int = Field(256, ge=1, le=10_000)
    states_per_seed: int | None = Field(None, ge=1, le=1_000_000, description="until: states: states counted per seed")
    leg_cap_states: int = Field(20_000, ge=1, le=1_000_000, description="a leg that counted this many states ends unsolved")
    key_paths: Literal["stratified"] = Field("stratified", description="each row explores the planner's key paths for "
                                             "the key-path seeds 1..key_path_pool, an equal share of seeds each")
    key_path_pool: int = Field(8, ge=1, le=64, description="key-path seeds per row (docs/survey.md, Key paths)")
    states_per_configuration: int | None = Field(None, ge=1, le=1_000_000,
                                                 description="the regrasp.survey/1 field: read as until: states with "
                                                 "this many states per seed")

    @model_validator(mode="after")
    def _check(self) -> "SurveySettings":
        if self.states_per_configuration is not None and self.states_per_seed is None:
            self.until, self.states_per_seed = "states", self.states_per_configuration
        if self.until == "states" and self.states_per_seed is None:
            raise ValueError("survey until: states needs states_per_seed")
        if self.seeds_max < self.seeds_min:
            raise ValueError(f"survey seeds_max {self.seeds_max} is below seeds_min {self.seeds_min}")
        return self


class Scenario(StrictModel):
    schema_: Literal["regrasp.scenario/1"] = Field(SCENARIO_SCHEMA, alias="schema")
    name: str
    description: str | None = None
    robot: str = "hrp5p"
    stance: str | StanceDef = "upright"
    object: ObjectDef
    start_pose: Pose7
    goal_pose: Pose7
    tables: list[BoxDef] = Field(default_factory=list, max_length=MAX_BOXES)
    obstacles: list[BoxDef] = Field(default_factory=list, max_length=MAX_BOXES)
    threshold_m: Finite = Field(0.0, ge=0, le=0.5, description="minimum CoM margin to the support polygon edge, m")
    hands: HandsChoice = "auto"
    limits: Limits = Field(default_factory=Limits)
    survey: SurveySettings = Field(default_factory=SurveySettings)
    seed: int = Field(1, ge=0, le=2**63 - 1)
    #: set by the planner when a built-in task is fitted to another robot (planner.scene.task_fitting): what it
    #: measured and chose; absent otherwise
    fitted: dict[str, Any] | None = None
    speed_scale: Finite = Field(1.0, gt=0, le=1, description="share of the time-optimal speed the plan is timed at")
    zmp_margin_m: Finite | None = Field(None, ge=0, le=0.5, description="how far inside the support polygon the "
                                        "timing keeps the ZMP, m; default the threshold, never below the safety floor")

    @model_validator(mode="after")
    def _check(self) -> "Scenario":
        if not self.tables:
            raise ValueError("a scenario needs at least one table for the start and goal poses")
        return self
