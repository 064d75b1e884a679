"""The /log line of an event: one readable sentence and a level by severity.

Failures, aborts, gate vetoes and refused commands are errors; rejections by an
approver, cancellations, expired approvals and a restart that continued a job are
warnings; progress ticks are debug; everything else is info.
"""

from __future__ import annotations

from typing import Any, Mapping

#: Job states that end in a failure of the job or of the robot's execution.
_ERROR_STATES = frozenset({"failed", "aborted"})
#: Job states that end or set back a job by someone's decision.
_WARNING_STATES = frozenset({"canceled", "rejected"})
#: Bridge events that report a robot-side problem.
_ERROR_BRIDGE = frozenset({"refused", "fault", "error", "lost", "timeout", "aborted", "stopped"})


def _state_of(payload: Mapping[str, Any]) -> str | None:
    state = payload.get("to", payload.get("state"))
    return state if isinstance(state, str) else None


def _verdict_failed(value: Any) -> bool:
    return isinstance(value, Mapping) and value.get("passed") is False


def level_of(kind: str, payload: Mapping[str, Any]) -> str:
    """``debug`` | ``info`` | ``warning`` | ``error`` for a record ``kind`` with ``payload``."""
    data = payload.get("data") if isinstance(payload.get("data"), Mapping) else {}
    if kind == "progress":
        return "debug"
    if kind.endswith(("error", "failed", "veto")):
        return "error"
    if kind == "state":
        state = _state_of(payload)
        if state in _ERROR_STATES:
            return "error"
        if state == "rejected":
            # A veto of the safety gate is an error; an approver's decision a warning.
            verdict = data.get("verdict") if isinstance(data, Mapping) else None
            return "error" if _verdict_failed(verdict) or data.get("execution") else "warning"
        if state in _WARNING_STATES:
            return "warning"
        if state == "planned" and isinstance(data, Mapping) and data.get("reason"):
            return "warning"  # sent back to planned (an expired approval)
        return "info"
    if kind in ("gate", "gate_verdict"):
        verdict = payload.get("verdict", data)
        return "error" if _verdict_failed(verdict) else "info"
    if kind in ("plan", "survey"):
        return "info"
    if kind in ("continued", "stop_sent"):
        return "warning"
    if kind == "finished":
        status = data.get("status") if isinstance(data, Mapping) else None
        return "info" if status in (None, "succeeded") else "error"
    if kind in _ERROR_BRIDGE or (isinstance(data, Mapping) and data.get("status") in _ERROR_BRIDGE):
        return "error"
    return "info"


def summarise(payload: Mapping[str, Any], limit: int = 160) -> str:
    """One short line for the Log panel (the full payload is in the event)."""
    if "to" in payload or "state" in payload:
        new = payload.get("to", payload.get("state"))
        text = f"{payload['from']} -> {new}" if payload.get("from") is not None else f"-> {new}"
        for key in ("reason", "message"):
            if payload.get(key):
                text += f" ({payload[key]})"
        for key in ("actor", "by"):
            if payload.get(key):
                text += f" by {payload[key]}"
        return text if len(text) <= limit else text[: limit - 3] + "..."
    if isinstance(payload.get("message"), str) and payload["message"]:
        return payload["message"] if len(payload["message"]) <= limit else payload["message"][: limit - 3] + "..."
    parts = []
    for key, value in payload.items():
        if isinstance(value, (str, int, float, bool)) or value is None:
            parts.append(f"{key}={value}")
        elif isinstance(value, (list, tuple)):
            parts.append(f"{key}=[{len(value)}]")
        elif isinstance(value, Mapping):
            parts.append(f"{key}={{{len(value)}}}")
    text = " ".join(parts)
    return text if len(text) <= limit else text[: limit - 3] + "..."
