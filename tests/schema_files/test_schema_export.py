"""``regrasp schema export DIR``: one JSON Schema file per wire model, none skipped."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from schemas import export
from service.cli.main import cli


def test_schema_export_writes_every_model(tmp_path: Path):
    out = tmp_path / "schemas"
    res = CliRunner().invoke(cli, ["schema", "export", str(out)], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    written = {Path(line).name for line in res.output.split()}
    expected = {f"{stem}.schema.json" for stem in export.EXPORTS}
    assert written == expected
    assert {p.name for p in out.iterdir()} == expected
    for name in expected:
        schema = json.loads((out / name).read_text())
        assert schema["$schema"].startswith("https://json-schema.org/") and schema.get("properties"), name
    # job-request is the body of POST /v1/jobs: {"kind", "request"}
    job_request = json.loads((out / "job-request.schema.json").read_text())
    assert set(job_request["required"]) == {"kind", "request"}
    assert "scenario" in json.dumps(job_request["$defs"])


def test_a_wrong_model_name_fails_loudly(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setitem(export.EXPORTS, "job-request", "schemas.jobs:NoSuchModel")
    with pytest.raises(AttributeError, match="NoSuchModel"):
        export.export_schemas(tmp_path)
    monkeypatch.setitem(export.EXPORTS, "job-request", "schemas.jobs:JobKind")
    with pytest.raises(TypeError, match="not a pydantic model"):
        export.export_schemas(tmp_path)
