"""A plan's own playback for Foxglove, on topics under ``/plan/``.

Sampled at ``plan_playback_rate_hz`` (the last point always included), at log
times ``t0 + t``: joint states and their transforms, the CoM, the ZMP, the object,
and one /plan/stability sample (margin, ZMP margin, effort) for the Plot panel.
Once, at ``t0``: the support polygon with its threshold band, the tables and the
planned CoM and ZMP ground paths. Every message carries its own instant only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterator, Mapping

import numpy as np

from . import foxglove_schemas as fx
from . import markers as mk
from .encoding import stamp
from .joints import joint_states_body, tf_body
from .settings import AuditSettings
from .topics import (
    NS_PER_S,
    TOPIC_EXECUTED_PLAN_COM,
    TOPIC_EXECUTED_PLAN_JOINTS,
    TOPIC_EXECUTED_PLAN_OBJECT,
    TOPIC_EXECUTED_PLAN_SCENE,
    TOPIC_EXECUTED_PLAN_STABILITY,
    TOPIC_EXECUTED_PLAN_SUPPORT,
    TOPIC_EXECUTED_PLAN_TF,
    TOPIC_EXECUTED_PLAN_ZMP,
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


@dataclass(frozen=True)
class PlaybackTopics:
    """Where a playback goes: the plan's own (``/plan/``) or the plan again on the execution's timeline."""

    joints: str
    tf: str
    com: str
    zmp: str
    object: str
    support: str
    scene: str
    stability: str


PLAN_TOPICS = PlaybackTopics(TOPIC_PLAN_JOINTS, TOPIC_PLAN_TF, TOPIC_PLAN_COM, TOPIC_PLAN_ZMP, TOPIC_PLAN_OBJECT,
                             TOPIC_PLAN_SUPPORT, TOPIC_PLAN_SCENE, TOPIC_PLAN_STABILITY)
EXECUTED_PLAN_TOPICS = PlaybackTopics(
    TOPIC_EXECUTED_PLAN_JOINTS, TOPIC_EXECUTED_PLAN_TF, TOPIC_EXECUTED_PLAN_COM, TOPIC_EXECUTED_PLAN_ZMP,
    TOPIC_EXECUTED_PLAN_OBJECT, TOPIC_EXECUTED_PLAN_SUPPORT, TOPIC_EXECUTED_PLAN_SCENE, TOPIC_EXECUTED_PLAN_STABILITY)


class Playback:
    """A plan's playback samples, ready to be stamped: its static markers once, then one group per sample."""

    def __init__(self, plan: Mapping[str, Any], settings: AuditSettings, tree: UrdfTree | None) -> None:
        self.plan = plan
        self.settings = settings
        self.tree = tree
        trajectory = plan.get("trajectory") or []
        self.joint_names = list((plan.get("robot") or {}).get("joint_names") or [])
        base_pose = (plan.get("stance") or {}).get("base_pose")
        self.base_pose = base_pose if base_pose is not None and len(base_pose) == 7 else None
        self.threshold = plan.get("threshold_m")
        self.dt = float(plan.get("dt_s") or 0.0)
        scenario = plan.get("scenario") if isinstance(plan.get("scenario"), Mapping) else {}
        self.shape = scenario.get("object") if isinstance(scenario.get("object"), Mapping) else None
        self.tables = [t for t in (scenario.get("tables") or []) + (scenario.get("obstacles") or [])
                       if isinstance(t, Mapping)]
        self.polygon = plan.get("support_polygon") or []
        #: Trajectory indices shown, and their points.
        self.indices = playback_indices(len(trajectory), self.dt, settings.plan_playback_rate_hz)
        self.points = [trajectory[i] for i in self.indices]
        self.com_path = [p["com"] for p in self.points if p.get("com") is not None]
        self.zmp_path = [p["zmp"] for p in self.points if p.get("zmp") is not None]
        self.zmp_margin = None
        if len(self.polygon) >= 3 and len(self.zmp_path) == len(self.points) and self.zmp_path:
            self.zmp_margin = mk.signed_distance(self.polygon, np.asarray(self.zmp_path, dtype=float))

    def t_of(self, k: int) -> float:
        """Plan time (s) of the ``k``-th sample shown."""
        return float(self.points[k].get("t", self.indices[k] * self.dt))

    def static(self, t0: int, topics: PlaybackTopics) -> Iterator[Message]:
        """The support polygon with its threshold band, the tables and the planned ground paths, at ``t0``."""
        lift = self.settings.marker_lift_m
        if len(self.polygon) >= 3:
            yield topics.support, fx.SCENE_UPDATE, mk.support_body(self.polygon, None, self.threshold, t0, lift), t0
        if self.tables or self.com_path or self.zmp_path:
            yield topics.scene, fx.SCENE_UPDATE, mk.path_body(self.com_path, self.zmp_path, self.tables, t0, lift), t0

    def sample(self, k: int, ns: int, topics: PlaybackTopics) -> Iterator[Message]:
        """The messages of the ``k``-th sample shown, stamped ``ns``."""
        i, point, settings, lift = self.indices[k], self.points[k], self.settings, self.settings.marker_lift_m
        q = point.get("q")
        if self.joint_names and q is not None:
            yield topics.joints, fx.JOINT_STATES, joint_states_body(self.joint_names, q, None, ns), ns
            tf = tf_body(self.tree, {str(n): float(v) for n, v in zip(self.joint_names, q)}, self.base_pose, "", ns)
            if tf is not None:
                yield topics.tf, fx.FRAME_TRANSFORMS, tf, ns
        com = point.get("com")
        if com is not None:
            body = mk.com_body(com, point.get("margin_m"), self.threshold, None, ns, settings.com_marker_diameter_m, lift)
            yield topics.com, fx.SCENE_UPDATE, body, ns
        zmp = point.get("zmp")
        if zmp is not None:
            inside = self.zmp_margin is None or bool(self.zmp_margin[k] >= 0)
            yield topics.zmp, fx.SCENE_UPDATE, mk.zmp_body(zmp, inside, ns, settings.zmp_marker_diameter_m, lift), ns
        pose = point.get("object_pose")
        if isinstance(pose, list) and len(pose) == 7:
            held = point.get("holding", "none") != "none"
            yield topics.object, fx.SCENE_UPDATE, mk.object_body(self.shape, pose, held, ns), ns
        seg = _segment_at(self.plan.get("segments"), i)
        stability = {"timestamp": stamp(ns), "index": i, "t": self.t_of(k),
                     "margin_m": point.get("margin_m"), "threshold_m": self.threshold,
                     "zmp_margin_m": None if self.zmp_margin is None else float(self.zmp_margin[k]),
                     "effort_ratio": point.get("effort_ratio"), "holding": point.get("holding"),
                     "segment": None if seg is None else f"{seg.get('kind')}/{seg.get('hand')}"}
        yield topics.stability, fx.PLAN_SAMPLE, stability, ns


def plan_messages(plan: Mapping[str, Any], t0: int, settings: AuditSettings, tree: UrdfTree | None) -> Iterator[Message]:
    """The playback messages of ``plan`` (``regrasp.plan/1``) starting at log time ``t0`` (ns)."""
    if not plan.get("trajectory"):
        return
    playback = Playback(plan, settings, tree)
    yield from playback.static(t0, PLAN_TOPICS)
    for k in range(len(playback.indices)):
        yield from playback.sample(k, t0 + int(round(playback.t_of(k) * NS_PER_S)), PLAN_TOPICS)
