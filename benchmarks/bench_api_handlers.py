"""Job handlers for benchmarks/bench_api.py: ``busy-S`` burns CPU for S seconds (polling cancel), ``trivial`` returns at once."""

from __future__ import annotations

import hashlib
import time
from typing import Any

from planner.errors import Canceled


def run(request: dict[str, Any], ctx: Any) -> dict[str, Any]:
    name = request["scenario"] if isinstance(request["scenario"], str) else "trivial"
    if name.startswith("busy-"):
        end = time.monotonic() + float(name[5:])
        digest = b"x"
        while time.monotonic() < end:
            for _ in range(500):
                digest = hashlib.sha256(digest).digest()
            if ctx.cancelled():
                raise Canceled()
    return {"schema": "bench/1", "status": "solved", "scenario": name}


HANDLERS = {"plan": "bench_api_handlers:run", "survey": "bench_api_handlers:run"}
