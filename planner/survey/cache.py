"""One survey answer per task: survey documents cached on disk by the hash of the resolved scenario.

``hands: auto``, the demo and the service's survey jobs all take the answer of the survey's
default estimator (the scenario's ``survey:`` field) for the task, computed once. The key is the
SHA-256 of the resolved scenario's canonical JSON (the form of plan hashes, docs/contract.md section
3) together with the robot model's fingerprint (its URDF's hash and its spec: effort limits and grip
live there), whether the effort and grip limits are checked, the survey schema and the hash of the
planner code that decides the counts, so a changed object, stance, threshold, seed, estimator,
robot, limit or code is a different task. Documents are written atomically (a
temporary file renamed into place), so processes sharing the folder (a service's workers) never
read half a document; two that compute the same task at once both write the same answer.

The folder is ``REGRASP_SURVEY_CACHE_DIR`` when set (the service sets it to ``<data dir>/survey-cache``),
else ``~/.cache/regrasp/surveys``.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable

from schemas.scenario import Scenario
from schemas.survey import SURVEY_SCHEMA

ENV_DIR = "REGRASP_SURVEY_CACHE_DIR"


def canonical(doc: Any) -> bytes:
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")


#: The planner's packages whose code decides a survey's counts: a change to any module in them is a new key.
SURVEY_PACKAGES = ("survey", "motion", "stability", "regrasp", "scene", "grasping", "kinematics", "robot", "compiled")


#: The planner package's folder.
PLANNER_ROOT = Path(__file__).resolve().parents[1]


def survey_code_files(root: Path = PLANNER_ROOT) -> list[Path]:
    """The modules of :data:`SURVEY_PACKAGES` under ``root``, in a fixed order (the compiled kernels' sources included)."""
    return sorted((p for pkg in SURVEY_PACKAGES for p in (root / pkg).rglob("*.py")),
                  key=lambda p: p.relative_to(root).as_posix())


def code_digest(root: Path = PLANNER_ROOT) -> str:
    """SHA-256 over the names and contents of :func:`survey_code_files` under ``root``."""
    h = hashlib.sha256()
    for path in survey_code_files(root):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(hashlib.sha256(path.read_bytes()).digest())
    return h.hexdigest()


@lru_cache(maxsize=1)
def code_version() -> str:
    """SHA-256 over the survey's code (a cached answer of older code is never reused)."""
    return code_digest()


def robot_fingerprint(robot: Any) -> str:
    """SHA-256 of what of a robot model decides a survey: its URDF's hash and its spec."""
    return hashlib.sha256(canonical({"urdf_sha256": robot.urdf_sha256,
                                     "spec": robot.spec.model_dump(mode="json")})).hexdigest()


def task_key(scenario: Scenario, robot_sha256: str, limits: bool = True) -> str:
    """The cache key of a resolved scenario: what decides its survey's answer (``robot_sha256`` from
    :func:`robot_fingerprint`; with or without the effort and grip limits)."""
    data = scenario.model_dump(by_alias=True, mode="json")
    data.pop("hands", None)  # what the plan asks for does not change the survey
    data.pop("description", None)
    data.pop("limits", None)  # planning limits; the survey stops on its own caps
    return hashlib.sha256(canonical({"scenario": data, "robot": robot_sha256, "schema": SURVEY_SCHEMA,
                                     "code": code_version(), "limits": bool(limits)})).hexdigest()


@dataclass(frozen=True)
class SurveyCache:
    """A folder of survey documents by task key."""

    directory: Path

    @classmethod
    def default(cls) -> "SurveyCache":
        env = os.environ.get(ENV_DIR)
        return cls(Path(env) if env else Path.home() / ".cache" / "regrasp" / "surveys")

    def path(self, key: str) -> Path:
        return self.directory / f"{key}.json"

    def get(self, key: str) -> dict[str, Any] | None:
        try:
            doc = json.loads(self.path(key).read_text())
        except (OSError, ValueError):
            return None
        return doc if isinstance(doc, dict) and doc.get("schema") == SURVEY_SCHEMA else None

    def put(self, key: str, doc: dict[str, Any]) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.directory, prefix=".tmp-", suffix=".json")
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(canonical(doc))
            os.replace(tmp, self.path(key))
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def key_for(self, scenario: Scenario, robot: Any = None, limits: bool = True) -> str:
        """The key of ``scenario`` surveyed with ``robot`` (default: the scenario's, loaded)."""
        if robot is None:
            from planner.robot.model import load_robot

            robot = load_robot(scenario.robot)
        return task_key(scenario, robot_fingerprint(robot), limits)

    def get_or_run(self, scenario: Scenario, run: Callable[[], dict[str, Any]], robot: Any = None,
                   limits: bool = True) -> dict[str, Any]:
        """The cached document of this task, or ``run()``'s, stored for the next caller.

        The document says whether it came from the cache in ``stats.cache`` ("hit" or "miss") and
        names its key in ``stats.task_key``."""
        key = self.key_for(scenario, robot, limits)
        doc = self.get(key)
        if doc is not None:
            doc.setdefault("stats", {})["cache"] = "hit"
            return doc
        doc = run()
        doc.setdefault("stats", {})["task_key"] = key
        self.put(key, doc)
        doc["stats"]["cache"] = "miss"
        return doc
