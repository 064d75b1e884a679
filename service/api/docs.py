"""The API's own documentation, served offline: ``/docs`` (Swagger UI) and ``/redoc`` (Redoc).

Both pages load their scripts from the package's vendored copies under ``/console/vendor/``
(see ``scripts/fetch_console_vendor.py``), never from a CDN, so they render in a lab without
internet. The OpenAPI document gets operationIds that read as verbs (``submitJob``,
``streamJobEvents``) and an example for every request body, so "Try it out" starts from a
request the service accepts.
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, FastAPI
from fastapi.responses import HTMLResponse
from fastapi.routing import APIRoute

VENDOR = "/console/vendor"
OPENAPI_URL = "/openapi.json"

#: Route function name -> operationId. Routes not listed get the camelCase of their function name.
OPERATION_IDS: dict[str, str] = {
    "submit": "submitJob",
    "list_jobs": "listJobs",
    "get_job": "getJob",
    "job_events": "streamJobEvents",
    "cancel": "cancelJob",
    "approve": "approveJob",
    "reject": "rejectJob",
    "dispatch": "dispatchJob",
    "stop": "stopJob",
    "audit": "downloadJobAudit",
    "job_risk": "getJobRisk",
    "catalogue": "getCatalogue",
    "robot_urdf": "getRobotUrdf",
    "robot_mesh": "getRobotMesh",
    "object_mesh": "getObjectMesh",
    "healthz": "checkHealth",
    "me": "getIdentity",
    "metrics": "getMetrics",
}

#: operationId -> named examples of its JSON request body (each one a request the service accepts).
BODY_EXAMPLES: dict[str, dict[str, dict[str, Any]]] = {
    "submitJob": {
        "plan": {"summary": "Plan the upright task with the scenario's own threshold and seed",
                 "value": {"kind": "plan", "request": {"scenario": "upright"}}},
        "plan-overrides": {"summary": "Plan with overrides: 30 mm threshold, left hand only, seed 7, 120 s limit",
                           "value": {"kind": "plan", "request": {"scenario": "upright", "threshold_m": 0.03,
                                                                 "hands": "left-left", "seed": 7, "time_limit_s": 120}}},
        "survey": {"summary": "Survey the crouched task in the staggered stance",
                   "value": {"kind": "survey", "request": {"scenario": "crouched", "stance": "staggered"}}},
    },
    "approveJob": {
        "approve": {"summary": "Approve the plan whose hash was reviewed",
                    "value": {"plan_sha256": "0" * 64, "comment": "margins reviewed on the risk card"}},
    },
    "rejectJob": {"reject": {"summary": "Reject with a reason", "value": {"reason": "the left hand passes too close to the table"}}},
    "cancelJob": {"cancel": {"summary": "Cancel with a reason", "value": {"reason": "submitted with the wrong stance"}}},
    "stopJob": {"stop": {"summary": "Stop with a reason", "value": {"reason": "person in the workspace"}}},
}


def operation_id(route: APIRoute) -> str:
    """The operationId of a route: listed above, else the camelCase of its function name."""
    if route.name in OPERATION_IDS:
        return OPERATION_IDS[route.name]
    head, *rest = route.name.split("_")
    return head + "".join(part.capitalize() for part in rest)


def add_body_examples(doc: dict[str, Any]) -> dict[str, Any]:
    """Put the examples above into the OpenAPI document's request bodies (in place; returned)."""
    for path_item in doc.get("paths", {}).values():
        for op in path_item.values():
            if not isinstance(op, dict):
                continue
            examples = BODY_EXAMPLES.get(op.get("operationId", ""))
            body = op.get("requestBody", {}).get("content", {}).get("application/json")
            if examples and body is not None:
                body["examples"] = examples
    return doc


SWAGGER_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title} - API (Swagger UI)</title>
<link rel="stylesheet" href="{vendor}/swagger-ui-dist/swagger-ui.css"></head>
<body><div id="swagger-ui"></div>
<script src="{vendor}/swagger-ui-dist/swagger-ui-bundle.js"></script>
<script>
window.ui = SwaggerUIBundle({{url: "{openapi}", dom_id: "#swagger-ui", deepLinking: true,
  presets: [SwaggerUIBundle.presets.apis], layout: "BaseLayout", persistAuthorization: true,
  validatorUrl: null}});
</script></body></html>"""

REDOC_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title} - API (Redoc)</title>
<style>body {{ margin: 0; }}</style></head>
<body><redoc spec-url="{openapi}"></redoc>
<script type="module" src="{vendor}/redoc/bundles/redoc.standalone.js"></script>
</body></html>"""


#: The docs pages may load only from this server. Redoc's bundle always asks for its attribution logo
#: on cdn.redoc.ly; this policy stops that request in the browser (the logo hides itself when it fails).
CSP = ("default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; "
       "img-src 'self' data:; font-src 'self' data:; connect-src 'self'; worker-src 'self' blob:")


def _page(html: str) -> HTMLResponse:
    return HTMLResponse(html, headers={"Content-Security-Policy": CSP})


def _title(app: FastAPI) -> str:
    return app.title.replace("<", "").replace(">", "")


def install(app: FastAPI) -> None:
    """Serve /docs and /redoc from the vendored assets; verb operationIds and body examples in /openapi.json.

    The app must be built with ``docs_url=None, redoc_url=None`` (FastAPI's own pages load from a CDN)
    and ``generate_unique_id_function=operation_id``.
    """
    router = APIRouter(include_in_schema=False)

    @router.get("/docs")
    def swagger_ui() -> HTMLResponse:
        return _page(SWAGGER_PAGE.format(title=_title(app), vendor=VENDOR, openapi=OPENAPI_URL))

    @router.get("/redoc")
    def redoc() -> HTMLResponse:
        return _page(REDOC_PAGE.format(title=_title(app), vendor=VENDOR, openapi=OPENAPI_URL))

    app.include_router(router)
