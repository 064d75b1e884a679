"""A plan's own playback for Foxglove, on topics under ``/plan/``.

Sampled at ``plan_playback_rate_hz`` (the last point always included), at log
times ``t0 + t``: joint states and their transforms, the CoM, the ZMP, the object,
and one /plan/stability sample (margin, ZMP margin, effort) for the Plot panel.
Once, at ``t0``: the support polygon with its threshold band, the tables and the
planned CoM and ZMP ground paths. Every message carries its own instant only.
"""

from __future__ import annotations

from typing import Any, Iterator, Mapping

import numpy as np

from . import foxglove_schemas as fx
from . import markers as mk
from .encoding import stamp
from .joints import joint_states_body, tf_body
from .settings import AuditSettings
from .topics import (
    NS_PER_S,
    TOPIC_PLAN_COM,
    TOPIC_PLAN_JOINTS,
    TOPIC_PLAN_OBJECT,
    TOPIC_PLAN_SCENE,
    TOPIC_PLAN_STABILITY,
    TOPIC_PLAN_SUPPORT,
    TOPIC_PLAN_TF,
    TOPIC_PLAN_ZMP,
)
from .urdf_frames import UrdfTree

Message = tuple[str, str, dict[str, Any], int]


def playback_indices(n: int, dt_s: float, rate_hz: float) -> list[int]:
    """Indices of the points shown: every ``1 / (rate dt)``-th one and the last."""
    if n == 0:
        return []
    stride = max(1, int(round(1.0 / (rate_hz * dt_s)))) if dt_s > 0 and rate_hz > 0 else 1
    indices = list(range(0, n, stride))
    if indices[-1] != n - 1:
        indices.append(n - 1)
    return indices


def _segment_at(segments: Any, i: int) -> Mapping[str, Any] | None:
    if not isinstance(segments, list):
        return None
    for seg in segments:
        if isinstance(seg, Mapping) and seg.get("first", 0) <= i <= seg.get("last", -1):
            return seg
    return None


def plan_messages(plan: Mapping[str, Any], t0: int, settings: AuditSettings, tree: UrdfTree | None) -> Iterator[Message]:
    """The playback messages of ``plan`` (``regrasp.plan/1``) starting at log time ``t0`` (ns)."""
    trajectory = plan.get("trajectory") or []
    if not trajectory:
        return
    joint_names = list((plan.get("robot") or {}).get("joint_names") or [])
    base_pose = (plan.get("stance") or {}).get("base_pose")
    if base_pose is not None and len(base_pose) != 7:
        base_pose = None
    threshold = plan.get("threshold_m")
    dt = float(plan.get("dt_s") or 0.0)
    scenario = plan.get("scenario") if isinstance(plan.get("scenario"), Mapping) else {}
    shape = scenario.get("object") if isinstance(scenario.get("object"), Mapping) else None
    tables = [t for t in (scenario.get("tables") or []) + (scenario.get("obstacles") or []) if isinstance(t, Mapping)]
    polygon = plan.get("support_polygon") or []
    lift = settings.marker_lift_m
    indices = playback_indices(len(trajectory), dt, settings.plan_playback_rate_hz)
    points = [trajectory[i] for i in indices]

    if len(polygon) >= 3:
        yield TOPIC_PLAN_SUPPORT, fx.SCENE_UPDATE, mk.support_body(polygon, None, threshold, t0, lift), t0
    com_path = [p["com"] for p in points if p.get("com") is not None]
    zmp_path = [p["zmp"] for p in points if p.get("zmp") is not None]
    if tables or com_path or zmp_path:
        yield TOPIC_PLAN_SCENE, fx.SCENE_UPDATE, mk.path_body(com_path, zmp_path, tables, t0, lift), t0
    zmp_margin = None
    if len(polygon) >= 3 and len(zmp_path) == len(points) and zmp_path:
        zmp_margin = mk.signed_distance(polygon, np.asarray(zmp_path, dtype=float))

    for k, (i, point) in enumerate(zip(indices, points)):
        ns = t0 + int(round(float(point.get("t", i * dt)) * NS_PER_S))
        q = point.get("q")
        if joint_names and q is not None:
            yield TOPIC_PLAN_JOINTS, fx.JOINT_STATES, joint_states_body(joint_names, q, None, ns), ns
            tf = tf_body(tree, {str(n): float(v) for n, v in zip(joint_names, q)}, base_pose, "", ns)
            if tf is not None:
                yield TOPIC_PLAN_TF, fx.FRAME_TRANSFORMS, tf, ns
        com = point.get("com")
        if com is not None:
            body = mk.com_body(com, point.get("margin_m"), threshold, None, ns, settings.com_marker_diameter_m, lift)
            yield TOPIC_PLAN_COM, fx.SCENE_UPDATE, body, ns
        zmp = point.get("zmp")
        if zmp is not None:
            inside = zmp_margin is None or bool(zmp_margin[k] >= 0)
            yield TOPIC_PLAN_ZMP, fx.SCENE_UPDATE, mk.zmp_body(zmp, inside, ns, settings.zmp_marker_diameter_m, lift), ns
        pose = point.get("object_pose")
        if isinstance(pose, list) and len(pose) == 7:
            held = point.get("holding", "none") != "none"
            yield TOPIC_PLAN_OBJECT, fx.SCENE_UPDATE, mk.object_body(shape, pose, held, ns), ns
        seg = _segment_at(plan.get("segments"), i)
        sample = {"timestamp": stamp(ns), "index": i, "t": float(point.get("t", i * dt)),
                  "margin_m": point.get("margin_m"), "threshold_m": threshold,
                  "zmp_margin_m": None if zmp_margin is None else float(zmp_margin[k]),
                  "effort_ratio": point.get("effort_ratio"), "holding": point.get("holding"),
                  "segment": None if seg is None else f"{seg.get('kind')}/{seg.get('hand')}"}
        yield TOPIC_PLAN_STABILITY, fx.PLAN_SAMPLE, sample, ns
