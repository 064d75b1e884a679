"""The console's fake API checked against the real service's OpenAPI document.

The fake (``fake_api.py``) lets the browser tests drive states that are slow or hard to reach
with the real service, but a hand-written copy drifts. So every request the page sends to the
fake and every JSON answer the fake gives is validated against the document the real app
generates (``service.app.create_app(...).openapi()``): the route and method must exist, the
status must be one the route declares, and request and response bodies must match the
declared schemas (JSON Schema 2020-12, as OpenAPI 3.1 embeds it). A change to the API's models
or routes therefore fails the console tests that exercise it.

A fake answer that imitates a different service on purpose (an older one without ``/v1/me``)
says so with the header ``X-Fake-Deviation`` and is not checked.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator

#: Paths of the API (the rest is the page, its assets and what a browser asks for by itself, like a favicon).
API_PATH = re.compile(r"^/(v1/|healthz$|metrics$)")
DEVIATION_HEADER = "x-fake-deviation"


def real_openapi() -> dict[str, Any]:
    """The OpenAPI document of the real service's app (built, not started: no store, no workers).

    Built in a child process run from the project's root, so that it is the document of this
    checkout's service (the test process has ``tests/`` on its path, whose ``schemas`` test
    package would shadow the project's).
    """
    root = Path(__file__).resolve().parents[2]
    code = ("import json, sys, tempfile\n"
            "from service.app import create_app\n"
            "from service.settings import ServiceSettings\n"
            "s = ServiceSettings(data_dir=tempfile.mkdtemp(prefix='regrasp-openapi-'), workers=1, preload_robot=False)\n"
            "sys.stdout.write(json.dumps(create_app(s, run_workers=False).openapi()))\n")
    env = {**os.environ, "PYTHONPATH": str(root)}
    out = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True,
                         timeout=120, check=True)
    return json.loads(out.stdout)


def _path_pattern(template: str) -> re.Pattern[str]:
    return re.compile("^" + re.sub(r"\\\{[^}]+\\\}", "[^/]+", re.escape(template)) + "$")


@dataclass
class ContractCheck:
    """Validates requests and responses against one OpenAPI document; collects what does not match."""

    doc: dict[str, Any]
    violations: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._routes = [(_path_pattern(p), p, item) for p, item in self.doc["paths"].items()]
        # Literal paths before templated ones (``/v1/jobs/{id}`` must not swallow a literal sibling).
        self._routes.sort(key=lambda r: r[1].count("{"))

    def operation(self, method: str, path: str) -> tuple[str, dict[str, Any]] | None:
        """The documented operation for a request, or None."""
        for pattern, template, item in self._routes:
            if pattern.match(path) and method.lower() in item:
                return template, item[method.lower()]
        return None

    def _validate(self, schema: dict[str, Any], value: Any) -> list[str]:
        wrapped = {**schema, "components": self.doc.get("components", {})}
        return [f"{'/'.join(str(p) for p in e.absolute_path) or '(body)'}: {e.message}"
                for e in Draft202012Validator(wrapped).iter_errors(value)]

    def check(self, method: str, path: str, request_body: bytes, status: int, content_type: str,
              response_body: bytes) -> list[str]:
        """Problems of one exchange (also appended to ``violations``)."""
        if not API_PATH.match(path):
            return []
        found = self.operation(method, path)
        where = f"{method} {path}"
        if found is None:
            problems = [f"{where}: no such operation in the real API"]
        else:
            template, op = found
            problems = []
            body_spec = op.get("requestBody")
            if request_body:
                if body_spec is None:
                    problems.append(f"{where}: the real API takes no request body here")
                else:
                    schema = body_spec["content"]["application/json"]["schema"]
                    problems += [f"{where} request {p}" for p in self._validate(schema, json.loads(request_body))]
            elif body_spec is not None and body_spec.get("required"):
                problems.append(f"{where}: the real API requires a request body")
            answer = op.get("responses", {}).get(str(status))
            if answer is None:
                problems.append(f"{where}: status {status} is not one the real API declares "
                                f"({', '.join(sorted(op.get('responses', {})))})")
            else:
                media = content_type.split(";")[0].strip()
                spec = answer.get("content", {}).get(media) or answer.get("content", {}).get("application/json")
                if spec is not None and "json" in media and response_body:
                    problems += [f"{where} -> {status} {p}"
                                 for p in self._validate(spec.get("schema", {}), json.loads(response_body))]
        self.violations += problems
        return problems


def install(app: Any, check: ContractCheck) -> None:
    """Check every exchange of a FastAPI app (the fake) against ``check``'s document."""
    from starlette.responses import Response

    @app.middleware("http")
    async def _contract(request: Any, call_next: Any) -> Any:
        body = await request.body()
        response = await call_next(request)
        media = response.headers.get("content-type", "")
        if "event-stream" in media or response.headers.get(DEVIATION_HEADER):
            return response
        chunks = [chunk async for chunk in response.body_iterator]
        payload = b"".join(chunks)
        check.check(request.method, request.url.path, body, response.status_code, media,
                    payload if "json" in media else b"")
        return Response(payload, status_code=response.status_code, headers=dict(response.headers),
                        media_type=response.media_type)
