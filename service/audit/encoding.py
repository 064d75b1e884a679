"""How audit messages become bytes: compact JSON, with stored documents spliced in verbatim.

A plan document is stored once as its canonical JSON text (``schemas.plan.canonical_json``); its
hash covers those bytes. :class:`RawJson` carries such a text into a message
unchanged, so a 9 MB plan is neither re-serialised nor given a second spelling in
the audit file.
"""

from __future__ import annotations

import json
import secrets
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .topics import NS_PER_S


@dataclass(frozen=True)
class RawJson:
    """A JSON text that goes into a message as it is (it must be one valid JSON value)."""

    text: str


def stamp(ns: int) -> dict[str, int]:
    """A foxglove time ``{"sec", "nsec"}`` from Unix nanoseconds."""
    return {"sec": ns // NS_PER_S, "nsec": ns % NS_PER_S}


def json_default(value: Any) -> Any:
    """Values json cannot write by itself: numpy arrays and scalars, datetimes, paths."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, RawJson):
        raise TypeError("a RawJson value is allowed only directly in an event payload")
    raise TypeError(f"cannot record a value of type {type(value).__name__} in the audit file")


def dumps(body: Mapping[str, Any]) -> bytes:
    """Compact JSON of ``body``; :class:`RawJson` values of ``body["payload"]`` are spliced in verbatim.

    NaN and Infinity are refused (ValueError), as the contract's canonical form refuses them.
    """
    payload = body.get("payload")
    raws: dict[str, str] = {}
    if isinstance(payload, Mapping) and any(isinstance(v, RawJson) for v in payload.values()):
        marker = secrets.token_hex(16)
        swapped = {}
        for key, value in payload.items():
            if isinstance(value, RawJson):
                token = f"\x00raw:{marker}:{len(raws)}"
                raws[json.dumps(token)] = value.text
                swapped[key] = token
            else:
                swapped[key] = value
        body = {**body, "payload": swapped}
    text = json.dumps(body, separators=(",", ":"), allow_nan=False, default=json_default)
    for quoted, raw in raws.items():
        text = text.replace(quoted, raw, 1)
    return text.encode("utf-8")
