"""One survey answer per task: survey documents cached on disk by the hash of the resolved scenario.

``hands: auto``, the demo and the service's survey jobs all take the answer of the survey's
default estimator (the scenario's ``survey:`` field) for the task, computed once. The key is the
SHA-256 of the resolved scenario's canonical JSON (the form of plan hashes, docs/contract.md section
3) together with the robot model's URDF hash, the survey schema and the survey code's hash, so a changed object, stance,
threshold, seed, estimator or robot is a different task. Documents are written atomically (a
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


#: The modules whose code decides a survey's counts: a change to any of them is a new key.
SURVEY_CODE = ("survey.py", "survey_counting.py", "survey_estimator.py", "trrt.py", "state_eval.py", "stances.py",
               "regrasp_planner.py", "regrasp_graph.py", "collision.py", "handover.py", "grasps.py")


@lru_cache(maxsize=1)
def code_version() -> str:
    """SHA-256 over the survey's code (a cached answer of older code is never reused)."""
    h = hashlib.sha256()
    here = Path(__file__).parent
    for name in SURVEY_CODE:
        path = here / name
        h.update(name.encode())
        h.update(path.read_bytes() if path.is_file() else b"-")
    return h.hexdigest()


def task_key(scenario: Scenario, urdf_sha256: str) -> str:
    """The cache key of a resolved scenario: what decides its survey's answer."""
    data = scenario.model_dump(by_alias=True, mode="json")
    data.pop("hands", None)  # what the plan asks for does not change the survey
    data.pop("description", None)
    data.pop("limits", None)  # planning limits; the survey stops on its own caps
    return hashlib.sha256(canonical({"scenario": data, "urdf_sha256": urdf_sha256, "schema": SURVEY_SCHEMA,
                                     "code": code_version()})).hexdigest()


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

    def get_or_run(self, scenario: Scenario, run: Callable[[], dict[str, Any]], urdf_sha256: str | None = None) -> dict[str, Any]:
        """The cached document of this task, or ``run()``'s, stored for the next caller.

        The document says whether it came from the cache in ``stats.cache`` ("hit" or "miss") and
        names its key in ``stats.task_key``."""
        if urdf_sha256 is None:
            from planner.robot.model import load_robot

            urdf_sha256 = load_robot(scenario.robot).urdf_sha256
        key = task_key(scenario, urdf_sha256)
        doc = self.get(key)
        if doc is not None:
            doc.setdefault("stats", {})["cache"] = "hit"
            return doc
        doc = run()
        doc.setdefault("stats", {})["task_key"] = key
        self.put(key, doc)
        doc["stats"]["cache"] = "miss"
        return doc
