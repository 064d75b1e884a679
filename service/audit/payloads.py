"""What the writer reads out of event payloads to derive its Foxglove views."""

from __future__ import annotations

import logging
from typing import Any, Mapping

from schemas.fast_json import loads

from .encoding import RawJson

_log = logging.getLogger("regrasp.audit")


def _as_doc(candidate: Any) -> Any:
    """A payload value as a document: stored JSON text (:class:`RawJson`) is parsed (fast)."""
    if isinstance(candidate, RawJson):
        try:
            return loads(candidate.text)
        except ValueError:
            return None
    return candidate


def find_plan(payload: Mapping[str, Any]) -> Mapping[str, Any] | None:
    """A plan document (``regrasp.plan/1``) as the payload or its ``document``/``plan``/``result``."""
    for candidate in (payload, payload.get("document"), payload.get("plan"), payload.get("result")):
        if isinstance(candidate, RawJson) and '"regrasp.plan/' not in candidate.text:
            continue  # a survey's text is not parsed for nothing
        doc = _as_doc(candidate)
        if isinstance(doc, Mapping) and str(doc.get("schema", "")).startswith("regrasp.plan/") and doc.get("trajectory"):
            return doc
    return None


def find_joint_state(payload: Mapping[str, Any]) -> tuple[list[str], list[float], list[float] | None] | None:
    """``joint_names`` with ``q`` (or ``positions``) in the payload or its ``data``/``payload``."""
    for candidate in (payload, payload.get("data"), payload.get("payload")):
        if not isinstance(candidate, Mapping):
            continue
        names = candidate.get("joint_names")
        q = candidate.get("q", candidate.get("positions"))
        if isinstance(names, (list, tuple)) and isinstance(q, (list, tuple)) and len(names) == len(q) and names:
            base = candidate.get("base_pose")
            return list(names), [float(v) for v in q], list(base) if base is not None else None
    return None


def find_balance(payload: Mapping[str, Any]) -> dict[str, float] | None:
    """A ``state/balance`` sample (the physics plant's) in the payload or its ``data``/``payload``, flattened for
    Foxglove's Plot panel; None when there is none."""
    for candidate in (payload, payload.get("data"), payload.get("payload")):
        if not isinstance(candidate, Mapping) or "foot_forces_n" not in candidate or "cop_margin_m" not in candidate:
            continue
        cop = candidate.get("cop") or [None, None]
        forces = candidate.get("foot_forces_n") or {}
        out = {"cop_x": cop[0], "cop_y": cop[1], "cop_margin_m": candidate.get("cop_margin_m"),
               "force_left_n": forces.get("left"), "force_right_n": forces.get("right"),
               "base_tilt_rad": candidate.get("base_tilt_rad"), "min_cop_margin_m": candidate.get("min_cop_margin_m")}
        return {k: float(v) for k, v in out.items() if isinstance(v, (int, float))}
    return None


def urdf_for(robot_name: str | None) -> str | None:
    """The URDF text of a known robot (from the planner's registry), or None."""
    if not robot_name:
        return None
    try:
        from planner.api.catalogue import urdf_path

        return urdf_path(str(robot_name)).read_text()
    except Exception as exc:  # noqa: BLE001 - unknown robot: the file simply has no model
        _log.warning("audit: no robot description for %r (%s)", robot_name, exc)
        return None
