"""A readable timeline of an audit file (``regrasp audit show``).

Events and log lines are listed one per line; high-rate channels (joint states,
/tf, markers) are summarised by count and time span, so a long execution stays
readable. The chain is verified while reading; the verdict ends the output.
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from .topics import TOPIC_EVENTS, TOPIC_LOG, TOPIC_ROBOT_DESCRIPTION
from .verify import VerifyResult, verify

NS_PER_S = 1_000_000_000


def _utc(ns: int) -> str:
    return datetime.fromtimestamp(ns / NS_PER_S, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]


def _short(value: Any, limit: int = 110) -> str:
    text = json.dumps(value, separators=(",", ":"), default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


#: Envelope fields of the service's events, left out of one-line summaries.
_ENVELOPE = {"event_id", "at", "job_id", "message"}


def _event_line(body: dict[str, Any]) -> str:
    kind = body.get("kind", "?")
    payload = body.get("payload") or {}
    if not isinstance(payload, dict):
        return f"{kind} {_short(payload)}"
    message = payload.get("message")
    if kind == "state":
        new = payload.get("to", payload.get("state"))
        old = payload.get("from")
        text = f"state {old} -> {new}" if old is not None else f"state -> {new}"
        for key in ("reason", "actor", "by"):
            if payload.get(key):
                text += f"  {key}: {payload[key]}"
        return text + (f"  ({message})" if message else "")
    if kind in ("plan", "survey"):
        doc = payload.get("document") if isinstance(payload.get("document"), dict) else payload
        keys = {k: doc.get(k) for k in ("status", "hands", "min_margin_m", "recommended") if k in doc}
        if payload.get("plan_sha256"):
            keys["plan_sha256"] = payload["plan_sha256"]
        return f"{kind} {_short(keys)}"
    rest = {k: v for k, v in payload.items() if k not in _ENVELOPE}
    text = f"{kind}"
    if message:
        text += f" {message!r}"
    return f"{text} {_short(rest)}" if rest else text


def timeline(path: str | Path, *, show_all: bool = False, head: str | None = None) -> tuple[list[str], VerifyResult]:
    """Lines of the timeline and the verification result of ``path``."""
    result = verify(path, head, keep_records=True)
    lines: list[str] = []
    if not result.entries:
        return lines, result
    t0 = result.entries[0].log_time_ns
    counts: dict[str, list[int]] = {}
    for entry in result.entries:
        rel = (entry.log_time_ns - t0) / NS_PER_S
        stamp = f"{_utc(entry.log_time_ns)}  +{rel:9.3f}s  #{entry.index:<6d}"
        if entry.topic == TOPIC_EVENTS:
            lines.append(f"{stamp} {_event_line(entry.message)}")
        elif entry.topic == TOPIC_LOG:
            if show_all:
                lines.append(f"{stamp} log: {entry.message.get('message', '')}")
        elif entry.topic == TOPIC_ROBOT_DESCRIPTION:
            size = len(entry.message.get("data", ""))
            lines.append(f"{stamp} robot description ({size} bytes of URDF)")
        else:
            span = counts.setdefault(entry.topic, [0, entry.log_time_ns, entry.log_time_ns])
            span[0] += 1
            span[1] = min(span[1], entry.log_time_ns)
            span[2] = max(span[2], entry.log_time_ns)
            if show_all:
                lines.append(f"{stamp} {entry.topic} ({entry.schema})")
    if counts:
        lines.append("")
        lines.append("channels summarised:")
        for topic, (n, first, last) in sorted(counts.items()):
            lines.append(f"  {topic:<24s} {n:6d} messages  +{(first - t0) / NS_PER_S:.3f}s .. +{(last - t0) / NS_PER_S:.3f}s")
    return lines, result
