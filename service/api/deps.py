"""Dependencies shared by the routes: the service object and the caller's identity."""

from __future__ import annotations

import contextvars
import logging
from typing import Any

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from schemas.jobs import Problem

from ..context import Service
from .auth import Principal, hash_token
from .problems import PROBLEM_MEDIA_TYPE, ProblemError

auth_log = logging.getLogger("regrasp.auth")
#: The authenticated caller's address, for the log lines of the route that serves it.
caller_address: contextvars.ContextVar[str] = contextvars.ContextVar("caller_address", default="?")
bearer = HTTPBearer(auto_error=False, description="Bearer token; roles planner, approver, operator, admin")


# The dependencies are ``async``: FastAPI runs a sync dependency in the thread pool, a thread hop
# per dependency per request, while these only read memory (a dict lookup of the token's hash).
async def service(request: Request) -> Service:
    return request.app.state.service


def client_address(request: Request) -> str:
    client = request.client
    return f"{client.host}:{client.port}" if client else "?"


async def principal(request: Request, creds: HTTPAuthorizationCredentials | None = Depends(bearer)) -> Principal:
    """The caller; a failed authentication is logged with the address (and the token's hash prefix, never the token)."""
    challenge = {"WWW-Authenticate": 'Bearer realm="regrasp"'}
    if creds is None:
        auth_log.warning("authentication failed from %s on %s %s: no bearer token (user unknown)",
                         client_address(request), request.method, request.url.path)
        raise ProblemError(401, "no bearer token: send 'Authorization: Bearer TOKEN'", headers=challenge)
    if creds.scheme.lower() != "bearer":
        auth_log.warning("authentication failed from %s on %s %s: scheme %r (user unknown)",
                         client_address(request), request.method, request.url.path, creds.scheme[:20])
        raise ProblemError(401, f"unsupported authorization scheme {creds.scheme[:20]!r}; use Bearer", headers=challenge)
    found = request.app.state.service.tokens.lookup(creds.credentials)
    if found is None:
        auth_log.warning("authentication failed from %s on %s %s: unknown token (user unknown, token sha256 %s...)",
                         client_address(request), request.method, request.url.path, hash_token(creds.credentials)[:12])
        raise ProblemError(401, "unknown bearer token", headers=challenge)
    caller_address.set(client_address(request))
    return found


def require(role: str, p: Principal, action: str) -> None:
    if not p.has(role):
        auth_log.warning("authorisation failed: user %r (roles %s) from %s: %s needs the role %r", p.user,
                         ",".join(sorted(p.roles)) or "none", caller_address.get(), action, role)
        raise ProblemError(403, f"{action} needs the role {role!r}; user {p.user!r} has {sorted(p.roles) or 'no roles'}")


def problems(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI entries for the problem responses a route can give."""
    descriptions = {400: "Bad request", 401: "Missing or unknown bearer token", 403: "Role missing or not allowed",
                    404: "No such job", 409: "The job's state does not allow this", 413: "Request body too large",
                    422: "Invalid request", 429: "Queue full; retry later", 503: "Service unavailable"}
    out: dict[int | str, dict[str, Any]] = {}
    for code in codes:
        entry: dict[str, Any] = {"model": Problem, "description": descriptions.get(code, "Error"),
                                 "content": {PROBLEM_MEDIA_TYPE: {}}}
        if code == 429:
            entry["headers"] = {"Retry-After": {"description": "seconds to wait", "schema": {"type": "integer"}}}
        if code == 401:
            entry["headers"] = {"WWW-Authenticate": {"description": "Bearer challenge", "schema": {"type": "string"}}}
        out[code] = entry
    return out
