"""The FastAPI application of the planning service (docs/contract.md section 5)."""

from __future__ import annotations

import logging
import time
from contextlib import asynccontextmanager
from typing import Any, AsyncIterator

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from starlette.middleware.gzip import GZipMiddleware

from .api import catalogue as catalogue_api
from .api import docs as docs_api
from .api import jobs as jobs_api
from .api import risk as risk_api
from .api import system as system_api
from .api.auth import TokenStore
from .api.problems import RequestBodyGuard, install_problem_handlers
from .context import Service
from .execution.bridge import Bridge
from .jobs.provenance import code_version
from .settings import ServiceSettings

log = logging.getLogger("regrasp.api")

DESCRIPTION = """Plans regrasp motions and stability surveys for the HRP-5P humanoid as jobs, with
approvals (two-person rule, bound to the plan's SHA-256) before anything is dispatched to the robot.

Job states: plan `queued -> planning -> planned -> approved -> dispatching -> executing -> succeeded`;
survey `queued -> planning -> succeeded`; ends `failed`, `canceled`, `rejected`, `aborted`.
Errors are RFC 9457 problem documents (`application/problem+json`)."""


def create_app(settings: ServiceSettings, *, tokens: TokenStore | None = None, run_workers: bool = True,
               bridge: Bridge | None = None) -> FastAPI:
    """Build the app; the job store, workers and audit pump start with the app's lifespan."""

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        svc = Service.build(settings, tokens=tokens, run_workers=run_workers, bridge=bridge)
        app.state.service = svc
        svc.start()
        log.info("service up: %s, %d worker(s), executor %s", svc.store.engine.dialect.name, settings.workers,
                 settings.executor)
        try:
            yield
        finally:
            svc.close()

    # docs_url/redoc_url None: FastAPI's pages load from a CDN; service.api.docs serves them from the package.
    app = FastAPI(title="Regrasp planning service", version=code_version(), description=DESCRIPTION,
                  lifespan=lifespan, docs_url=None, redoc_url=None,
                  generate_unique_id_function=docs_api.operation_id)
    install_problem_handlers(app)
    app.include_router(jobs_api.router)
    app.include_router(risk_api.router)
    app.include_router(catalogue_api.router)
    app.include_router(system_api.router)
    docs_api.install(app)
    if system_api.CONSOLE_DIR.is_dir():
        app.mount("/console", StaticFiles(directory=system_api.CONSOLE_DIR, html=True), name="console")

    app.add_middleware(RequestMetrics)
    app.add_middleware(SelectiveGZip, minimum_size=settings.gzip_min_bytes)
    app.add_middleware(RequestBodyGuard, max_bytes=settings.max_body_bytes, read_timeout_s=settings.body_read_timeout_s)
    _problem_openapi(app)
    return app


class SelectiveGZip:
    """gzip for large responses, except streams whose bytes must go out as they come (SSE, audit files)."""

    #: Path endings whose responses are streamed as they are produced, never buffered for compression.
    STREAMED = ("/events", "/audit")

    def __init__(self, app: Any, minimum_size: int) -> None:
        self.app = app
        self.gzip = GZipMiddleware(app, minimum_size=minimum_size)

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "http" or scope.get("path", "").endswith(self.STREAMED):
            await self.app(scope, receive, send)
            return
        await self.gzip(scope, receive, send)


class RequestMetrics:
    """Pure ASGI middleware timing every request into the latency histogram (cheaper than BaseHTTPMiddleware)."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status = 500

        async def send_wrapper(message: dict[str, Any]) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            svc = getattr(scope.get("app").state, "service", None) if scope.get("app") is not None else None
            if svc is not None:
                route = getattr(scope.get("route"), "path", "unmatched")
                svc.metrics.http_latency.labels(scope["method"], route, str(status)).observe(time.perf_counter() - start)


def _problem_openapi(app: FastAPI) -> None:
    """Document problem responses under ``application/problem+json`` only (FastAPI adds application/json)."""
    original = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is not None:
            return app.openapi_schema
        doc = original()
        for path_item in doc.get("paths", {}).values():
            for op in path_item.values():
                for resp in op.get("responses", {}).values():
                    content = resp.get("content", {})
                    if "application/problem+json" in content and "application/json" in content:
                        content["application/problem+json"] = content.pop("application/json")
        app.openapi_schema = docs_api.add_body_examples(doc)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
