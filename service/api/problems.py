"""RFC 9457 problem documents for every error the API returns.

Routes raise :class:`ProblemError`; FastAPI's own errors (validation, unknown
route, wrong method) and unexpected exceptions are converted by the handlers
installed with :func:`install_problem_handlers`, so a client always gets
``application/problem+json`` with a ``detail`` that says what to fix.
"""

from __future__ import annotations

import asyncio
import logging
import re
import uuid
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DBAPIError
from starlette.exceptions import HTTPException as StarletteHTTPException

from service.errors import RegraspServiceError

PROBLEM_MEDIA_TYPE = "application/problem+json"
PROBLEM_TYPE_BASE = "https://regrasp.invalid/problems/"
log = logging.getLogger("regrasp.api")
#: Validation errors listed in a 422 (a 150,000-item list of wrong types has as many errors).
MAX_REPORTED_ERRORS = 20


class ProblemError(RegraspServiceError):
    """An error answered as a problem document."""

    def __init__(self, status: int, detail: str, *, title: str | None = None, type_: str | None = None,
                 headers: dict[str, str] | None = None, **extensions: Any) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.title = title or HTTPStatus(status).phrase
        self.type = type_ or "about:blank"
        self.headers = headers or {}
        self.extensions = extensions


def problem_response(status: int, detail: str, *, title: str | None = None, type_: str = "about:blank",
                     instance: str | None = None, headers: dict[str, str] | None = None,
                     **extensions: Any) -> JSONResponse:
    body: dict[str, Any] = {"type": type_, "title": title or HTTPStatus(status).phrase, "status": status,
                            "detail": detail}
    if instance:
        body["instance"] = instance
    body.update(extensions)
    return JSONResponse(body, status_code=status, media_type=PROBLEM_MEDIA_TYPE, headers=headers)


_CLASS_MENTION = re.compile(r"(?: or)? (?:an )?instance of [A-Za-z_][A-Za-z0-9_.]*")


def clean_message(message: str) -> str:
    """A validation message without the names of Python classes (pydantic writes "... or instance of BoxDef")."""
    return _CLASS_MENTION.sub("", message)


def _format_loc(loc: tuple[Any, ...] | list[Any]) -> str:
    parts = [str(p) for p in loc]
    if parts and parts[0] in ("body", "query", "path", "header"):
        where, rest = parts[0], parts[1:]
        return f"{where} {'.'.join(rest)}" if rest else where
    return ".".join(parts) or "request"


def _leaf_routes(routes: Any) -> Any:
    """The routes themselves, with included routers opened (FastAPI wraps each ``include_router``)."""
    for route in routes:
        inner = getattr(route, "original_router", None)
        if inner is not None:
            yield from _leaf_routes(inner.routes)
        else:
            yield route


def _allowed_methods(request: Request) -> list[str]:
    """Every method some route serves at this path (Starlette's own Allow names only the first route's)."""
    from starlette.routing import Match

    methods: set[str] = set()
    for route in _leaf_routes(request.app.router.routes):
        match, _ = route.matches({**request.scope, "method": "__none__"})
        if match != Match.NONE and getattr(route, "methods", None):
            methods |= set(route.methods)
    return sorted(methods)


def install_problem_handlers(app: FastAPI) -> None:
    @app.exception_handler(ProblemError)
    async def _problem(request: Request, exc: ProblemError) -> JSONResponse:
        return problem_response(exc.status, exc.detail, title=exc.title, type_=exc.type,
                                instance=request.url.path, headers=exc.headers, **exc.extensions)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = []
        lines = []
        found = exc.errors()
        for err in found[:MAX_REPORTED_ERRORS]:
            where = _format_loc(err.get("loc", ()))
            msg = clean_message(str(err.get("msg", "invalid")))
            errors.append({"location": where, "message": msg, "type": str(err.get("type", ""))})
            lines.append(f"{where}: {msg}")
        detail = "the request is invalid: " + "; ".join(lines[:10]) + (f" (and {len(found) - 10} more)" if len(found) > 10 else "")
        return problem_response(422, detail, type_=PROBLEM_TYPE_BASE + "validation", instance=request.url.path,
                                errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else HTTPStatus(exc.status_code).phrase
        if exc.status_code == 400 and detail == "There was an error parsing the body":
            detail = "the request body could not be parsed: send UTF-8 JSON with Content-Type: application/json"
        if exc.status_code == 404 and detail == "Not Found":
            detail = f"there is no resource at {request.url.path}; the API lives under /v1 (see /docs)"
        headers = dict(exc.headers or {})
        if exc.status_code == 405:
            allowed = _allowed_methods(request)
            headers["Allow"] = ", ".join(allowed)
            detail = f"method {request.method} is not allowed on {request.url.path}; allowed: {', '.join(allowed)}"
        return problem_response(exc.status_code, detail, instance=request.url.path, headers=headers)

    @app.exception_handler(DBAPIError)
    async def _database(request: Request, exc: DBAPIError) -> JSONResponse:
        storage = getattr(getattr(request.app.state, "service", None), "storage", None)
        reason = storage.note_failure(exc, f"{request.method} {request.url.path}") if storage is not None else None
        if reason is not None:
            return problem_response(503, f"the service cannot keep data: {reason}", title="Storage unavailable",
                                    instance=request.url.path, headers={"Retry-After": "5"})
        ref = uuid.uuid4().hex[:12]
        log.error("job store error on %s %s (ref %s): %s", request.method, request.url.path, ref,
                  str(exc.orig if exc.orig is not None else exc).splitlines()[0][:300])
        return problem_response(503, f"the job store is unavailable or damaged; retry later, and tell the operator "
                                     f"(log reference {ref})", instance=request.url.path,
                                headers={"Retry-After": "5"})

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        ref = uuid.uuid4().hex[:12]
        log.exception("unhandled error on %s %s (ref %s)", request.method, request.url.path, ref)
        return problem_response(500, f"internal error; the service log has the details (reference {ref})",
                                instance=request.url.path)


#: Media types a request body may have: JSON (``application/json``, ``application/*+json``).
JSON_TYPES = ("application/json",)


def _is_json(content_type: str) -> bool:
    media = content_type.split(";", 1)[0].strip().lower()
    return media in JSON_TYPES or (media.startswith("application/") and media.endswith("+json"))


class RequestBodyGuard:
    """ASGI middleware bounding every request body before the app sees it.

    The body is read here in full, against three limits, and handed to the app only once it
    is complete:

    - size: over ``max_bytes`` gets 413, whether declared by ``Content-Length`` or streamed in
      chunks (the reading stops at the limit, so a large chunked body costs at most ``max_bytes``);
    - time: a body not complete within ``read_timeout_s`` gets 408 and the connection is closed,
      so a client that declares 1,000 bytes and sends 10 holds a connection for that long at most;
    - type: a non-empty body that is not JSON gets 415.
    """

    def __init__(self, app: Any, max_bytes: int, read_timeout_s: float) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.read_timeout_s = read_timeout_s

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {name: value for name, value in scope.get("headers", [])}
        declared: int | None = None
        if b"content-length" in headers:
            try:
                declared = int(headers[b"content-length"])
            except ValueError:
                declared = -1
            if declared < 0:
                await _reply(send, scope, 400, "the Content-Length header is not a byte count")
                return
            if declared > self.max_bytes:
                await _reply(send, scope, 413, f"the request body ({declared} bytes) is over the limit of "
                                               f"{self.max_bytes} bytes")
                return
        chunked = b"chunked" in headers.get(b"transfer-encoding", b"").lower()
        if not declared and not chunked:
            await self.app(scope, receive, send)
            return
        content_type = headers.get(b"content-type", b"application/json").decode("latin-1")
        if not _is_json(content_type):
            await _reply(send, scope, 415, f"the request body is {content_type.split(';')[0]!r}; send JSON with "
                                           "Content-Type: application/json")
            return
        body = bytearray()
        deadline = asyncio.get_running_loop().time() + self.read_timeout_s
        while True:
            left = deadline - asyncio.get_running_loop().time()
            try:
                message = await asyncio.wait_for(receive(), timeout=max(left, 0.0))
            except asyncio.TimeoutError:
                log.warning("request body of %s %s from %s not complete after %.1f s (%d bytes read): closed",
                            scope.get("method"), scope.get("path"), _client(scope), self.read_timeout_s, len(body))
                await _reply(send, scope, 408, f"the request body was not received within {self.read_timeout_s:g} s "
                                               f"({len(body)} bytes arrived)", close=True)
                return
            if message["type"] == "http.disconnect":
                return
            body += message.get("body", b"")
            if len(body) > self.max_bytes:
                await _reply(send, scope, 413, f"the request body is over the limit of {self.max_bytes} bytes "
                                               f"(more than {self.max_bytes} bytes arrived)", close=True)
                return
            if not message.get("more_body", False):
                break
        replayed = False

        async def replay() -> dict[str, Any]:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": bytes(body), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


def _client(scope: dict[str, Any]) -> str:
    client = scope.get("client")
    return f"{client[0]}:{client[1]}" if client else "?"


async def _reply(send: Any, scope: dict[str, Any], status: int, detail: str, *, close: bool = False) -> None:
    headers = {"Connection": "close"} if close else None
    response = problem_response(status, detail, instance=scope.get("path"), headers=headers)
    await response({"type": "http"}, None, send)  # type: ignore[arg-type]
