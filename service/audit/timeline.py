"""A readable timeline of an audit file (``regrasp audit show``).

Events and log lines are listed one per line; high-rate channels (joint states,
/tf, markers) are summarised by count and time span, so a long execution stays
readable. The chain is verified while reading; the verdict ends the output.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from .topics import TOPIC_EVENTS, TOPIC_LOG, TOPIC_ROBOT_DESCRIPTION
from .verify import VerifyResult, verify

NS_PER_S = 1_000_000_000


def _utc(ns: int) -> str:
    return datetime.fromtimestamp(ns / NS_PER_S, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]


def _words(value: Any, depth: int = 0) -> str:
    """A value as words for people: ``collision 1, ik 3`` rather than ``{'collision': 1, 'ik': 3}``."""
    if isinstance(value, dict):
        if not value:
            return "none"
        inner = ", ".join(f"{str(k).replace('_', ' ')} {_words(v, depth + 1)}" for k, v in value.items())
        return f"({inner})" if depth else inner
    if isinstance(value, (list, tuple)):
        return "none" if not value else ", ".join(_words(v, depth + 1) for v in value)
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.6g}"
    if value is None:
        return "-"
    return str(value)


def _short(value: Any, limit: int = 110) -> str:
    text = _words(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


#: Envelope fields of the service's events, left out of one-line summaries.
_ENVELOPE = {"event_id", "at", "job_id", "message"}


def _plan_words(doc: dict[str, Any], sha: str | None) -> str:
    parts = [str(doc[k]) for k in ("status",) if doc.get(k)]
    if doc.get("hands"):
        parts.append(f"hands {doc['hands']}")
    if isinstance(doc.get("min_margin_m"), (int, float)):
        parts.append(f"min margin {doc['min_margin_m'] * 1000:.1f} mm")
    if doc.get("recommended"):
        parts.append(f"recommended {doc['recommended']}")
    if sha:
        parts.append(f"sha256 {sha[:12]}")
    return ", ".join(parts)


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
        data = payload.get("data") if isinstance(payload.get("data"), dict) else {}
        for key in ("reason", "actor", "by"):
            value = payload.get(key) or data.get(key)
            if value:
                text += f"  {key}: {value}"
        return text + (f"  ({message})" if message else "")
    if kind in ("plan", "survey"):
        doc = payload.get("document") if isinstance(payload.get("document"), dict) else payload
        return f"{kind} {_plan_words(doc, payload.get('plan_sha256'))}".rstrip()
    rest = {k: v for k, v in payload.items() if k not in _ENVELOPE}
    text = f"{kind}"
    if message:
        text += f": {message}"
    return f"{text}: {_short(rest)}" if rest and not message else (f"{text} ({_short(rest)})" if rest else text)


def timeline(path: str | Path, *, show_all: bool = False, head: str | None = None) -> tuple[list[str], VerifyResult]:
    """Lines of the timeline and the verification result of ``path``."""
    result = verify(path, head, keep_records=True)
    lines: list[str] = []
    if not result.entries:
        return lines, result
    t0 = min(entry.log_time_ns for entry in result.entries)  # offsets count from the earliest event: never negative
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
