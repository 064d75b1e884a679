"""``/healthz``, ``/metrics``, ``/v1/me`` and the operator console (``/`` and ``/console/``)."""

from __future__ import annotations

import logging
import secrets
from pathlib import Path
from typing import Literal

from fastapi import APIRouter, Depends, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, HTMLResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from schemas.common import StrictModel
from schemas.jobs import Health

from ..context import Service
from ..jobs.provenance import code_version
from .auth import Principal
from .deps import client_address, principal, problems, service
from .problems import ProblemError

router = APIRouter(tags=["system"])
log = logging.getLogger("regrasp.api")
CONSOLE_DIR = Path(__file__).resolve().parent.parent / "console"

PLACEHOLDER = """<!doctype html><html><head><meta charset="utf-8"><title>regrasp service</title></head>
<body><h1>Regrasp planning service</h1><p>The operator console is not installed
(service/console/index.html). The API is documented at <a href="/docs">/docs</a>.</p></body></html>"""


@router.get("/healthz", response_model=Health, summary="Liveness and readiness", responses=problems(503))
def healthz(svc: Service = Depends(service)) -> Health:
    sick = svc.storage.check() if svc.storage is not None else None
    if sick is not None:
        raise ProblemError(503, f"the service cannot keep data: {sick}", title="Storage unavailable",
                           headers={"Retry-After": str(svc.settings.retry_after_s)})
    try:
        depth = svc.store.queue_depth()
    except Exception as exc:  # noqa: BLE001
        log.error("health check: the job store is unreachable: %s", str(exc).splitlines()[0][:300] if str(exc) else exc)
        raise ProblemError(503, "the job store is unreachable or damaged; the service log has the details",
                           headers={"Retry-After": str(svc.settings.retry_after_s)}) from None
    workers = svc.executor.total_slots() if svc.executor is not None else 0
    runner_ok = svc.runner is None or (svc.runner._thread is not None and svc.runner._thread.is_alive())  # noqa: SLF001
    return Health(status="ok" if runner_ok else "degraded", database=svc.store.engine.dialect.name,
                  executor=svc.executor.name if svc.executor is not None else "none", workers=workers,
                  queue_depth=depth, controller_alive=svc.bridge.controller_alive(), version=code_version(),
                  robot_id=getattr(svc.bridge, "robot_id", None), balance_age_s=_balance_age(svc))


def _balance_age(svc: Service) -> float | None:
    """Seconds since the physics plant's last balance sample reached the service (None: none has, or no watch)."""
    return None if svc.executions.balance is None else svc.executions.balance.last_sample_age_s()


class Identity(StrictModel):
    """Who a bearer token is. ``admin`` holds every role; the two-person rule and "submitter or admin" still
    depend on the job, so the console decides its buttons from this and the job together."""

    user: str
    roles: list[Literal["planner", "approver", "operator", "admin"]]


@router.get("/v1/me", response_model=Identity, summary="The caller's user and roles (for the console's buttons)",
            responses=problems(401))
def me(p: Principal = Depends(principal)) -> Identity:
    return Identity(user=p.user, roles=sorted(p.roles))


@router.get("/metrics", summary="Prometheus metrics (bearer token)", response_class=Response,
            openapi_extra={"security": [{"HTTPBearer": []}]},
            responses={**problems(401), 200: {"content": {CONTENT_TYPE_LATEST.split(";")[0]: {"schema": {"type": "string"}}},
                             "description": "Prometheus text format"}})
async def metrics(request: Request, svc: Service = Depends(service)) -> Response:
    """Behind a bearer token: the settings' ``metrics_token`` (for Prometheus) or any user's token.

    A deployment that wants a scraper without tokens serves the same registry on a separate
    bind instead (``metrics_port``, loopback by default).
    """
    header = request.headers.get("authorization", "")
    scheme, _, token = header.partition(" ")
    token = token.strip()
    allowed = scheme.lower() == "bearer" and token != "" and (
        (svc.settings.metrics_token is not None and secrets.compare_digest(token, svc.settings.metrics_token))
        or svc.tokens.lookup(token) is not None)
    if not allowed:
        log.warning("metrics: authentication failed from %s (%s)", client_address(request),
                    "no bearer token" if not token else "unknown token")
        raise ProblemError(401, "/metrics needs a bearer token (the service's metrics token or a user's token)",
                           headers={"WWW-Authenticate": 'Bearer realm="regrasp"'})
    body = await run_in_threadpool(generate_latest, svc.metrics.registry)
    return Response(body, media_type=CONTENT_TYPE_LATEST)


@router.get("/", include_in_schema=False)
def root() -> Response:
    index = CONSOLE_DIR / "index.html"
    if index.is_file():
        return FileResponse(index, media_type="text/html")
    return HTMLResponse(PLACEHOLDER)
