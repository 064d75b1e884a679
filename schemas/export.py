"""JSON Schema export of the wire contract, for clients in other languages."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

from pydantic import BaseModel

#: file stem -> "module:Model"; a name that does not resolve to a pydantic model is an error.
EXPORTS: dict[str, str] = {
    "scenario": "schemas.scenario:Scenario",
    "stance": "schemas.stance:StanceDef",
    "plan": "schemas.plan:Plan",
    "survey": "schemas.survey:Survey",
    "job": "schemas.jobs:Job",
    "job-request": "schemas.jobs:JobSubmit",
    "bridge-trajectory-segment": "schemas.bridge:TrajectorySegment",
    "bridge-stop": "schemas.bridge:Stop",
    "bridge-joint-state": "schemas.bridge:JointState",
    "bridge-exec-status": "schemas.bridge:ExecStatus",
    "bridge-heartbeat": "schemas.bridge:Heartbeat",
    "gate-verdict": "schemas.bridge:GateVerdict",
}


def available_models() -> dict[str, type[BaseModel]]:
    """Every exported model by file stem; raises if an entry of :data:`EXPORTS` names no pydantic model."""
    out: dict[str, type[BaseModel]] = {}
    for stem, ref in EXPORTS.items():
        module_name, attr = ref.split(":")
        model = getattr(importlib.import_module(module_name), attr)
        if not (isinstance(model, type) and issubclass(model, BaseModel)):
            raise TypeError(f"EXPORTS[{stem!r}] = {ref!r} is not a pydantic model")
        out[stem] = model
    return out


def export_schemas(directory: Path) -> list[Path]:
    """Write one ``<name>.schema.json`` per wire model; returns the written paths."""
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for stem, model in available_models().items():
        schema = model.model_json_schema(by_alias=True)
        schema.setdefault("$schema", "https://json-schema.org/draft/2020-12/schema")
        schema.setdefault("$id", f"https://hrp-regrasp.invalid/schemas/{stem}.schema.json")
        path = directory / f"{stem}.schema.json"
        path.write_text(json.dumps(schema, indent=2, sort_keys=True) + "\n")
        written.append(path)
    return written
