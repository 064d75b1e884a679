"""Fast parsing of large JSON documents (plans of several MB) with orjson.

Only for *reading*: the bytes a hash covers are always written by
``json.dumps`` in the contract's canonical form (schemas.plan.canonical_json),
since orjson spells some floats differently. orjson refuses NaN/Infinity
literals, as the canonical form does; integers beyond 64 bits, which it also
refuses, fall back to the standard library.
"""

from __future__ import annotations

import json
from typing import Any

import orjson


def loads(data: bytes | bytearray | memoryview | str) -> Any:
    """Parse JSON text; raises ValueError (as json.loads does) on malformed input."""
    try:
        return orjson.loads(data)
    except orjson.JSONDecodeError as exc:
        if "integer" in str(exc).lower():
            return json.loads(data)
        raise ValueError(str(exc)) from None
