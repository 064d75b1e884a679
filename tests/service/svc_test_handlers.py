"""Job handlers for the service tests: real CPU work with progress and cancel polling.

The scenario name selects the behaviour (the service's name check is off in
these tests): ``busy-S`` computes hashes for S seconds, reporting progress and
polling ``ctx.cancelled()`` every few milliseconds; ``hang-S`` computes without
ever polling (only a kill stops it); ``crash`` kills its own process; ``error``
raises; ``infeasible`` returns an infeasible plan; ``quick`` returns at once.
"""

from __future__ import annotations

import hashlib
import os
import signal
import time
from typing import Any

from planner.entry import Canceled


def _spin(seconds: float, ctx: Any, poll: bool) -> int:
    end = time.monotonic() + seconds
    start = time.monotonic()
    digest = b"seed"
    n = 0
    while time.monotonic() < end:
        for _ in range(200):
            digest = hashlib.sha256(digest).digest()
        n += 1
        if poll:
            if ctx.cancelled():
                raise Canceled("canceled while busy")
            ctx.progress(min(1.0, (time.monotonic() - start) / max(seconds, 1e-9)), f"busy {n}")
    return n


def _plan_doc(request: dict[str, Any], **extra: Any) -> dict[str, Any]:
    return {"schema": "test/1", "status": "solved", "failure": None, "seed": request.get("seed") or 0,
            "request": request, **extra}


def run(request: dict[str, Any], ctx: Any) -> dict[str, Any]:
    name = request["scenario"] if isinstance(request["scenario"], str) else "quick"
    mode, _, arg = name.partition("-")
    if mode == "busy":
        n = _spin(float(arg or 1.0), ctx, poll=True)
        return _plan_doc(request, iterations=n)
    if mode == "hang":
        n = _spin(float(arg or 30.0), ctx, poll=False)
        return _plan_doc(request, iterations=n)
    if mode == "crash":
        ctx.progress(0.1, "about to crash")
        time.sleep(0.2)
        os.kill(os.getpid(), signal.SIGKILL)
    if mode == "error":
        raise RuntimeError("the test handler failed on purpose")
    if mode == "infeasible":
        return {"schema": "test/1", "status": "infeasible",
                "failure": {"code": "COM_MARGIN", "message": "no plan keeps the margin", "counts": {}}}
    ctx.progress(1.0, "quick")
    return _plan_doc(request)


HANDLERS = {"plan": "svc_test_handlers:run", "survey": "svc_test_handlers:run"}
