"""AuditWriter: one MCAP file per job, hash-chained, readable in Foxglove.

Layout of a file (all channels JSON-encoded, schema names Foxglove knows):

====================  ========================  =====================================
topic                 schema                    what
====================  ========================  =====================================
/audit/events         regrasp.audit.Event       every state change, request, plan,
                                                survey, approval, gate verdict,
                                                dispatched segment (``record``)
/log                  foxglove.Log              a readable line per event (Log panel)
/robot_description    std_msgs/String           the URDF; Foxglove's 3D panel loads it
/joint_states/plan    foxglove.JointStates      the plan, sampled for playback
/joint_states/executed foxglove.JointStates     the robot state echoed back
/tf                   foxglove.FrameTransforms  world -> root link and every moving
                                                joint (plan unprefixed, executed
                                                under ``executed/``)
/markers/com          foxglove.SceneUpdate      CoM sphere, its ground projection,
                                                margin text, the CoM trace
/markers/support      foxglove.SceneUpdate      support polygon and the polygon
                                                shrunk by the threshold
====================  ========================  =====================================

Every message is one link of the hash chain (:mod:`service.audit.chain`). After
each call the open chunk is closed and the stream flushed, so a writer killed
with SIGKILL leaves a file that :func:`service.audit.verify.verify` reads up to
its last complete call (exit code 2, "unfinished").
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Literal, Mapping, Sequence

import numpy as np
from mcap.writer import CompressionType, Writer
from pydantic_settings import BaseSettings, SettingsConfigDict

from . import foxglove_schemas as fx
from .chain import CHAIN_FORMAT, GENESIS, record_digest
from .urdf_frames import WORLD_FRAME, UrdfTree, joint_transforms, parse_urdf

NS_PER_S = 1_000_000_000
_log = logging.getLogger("regrasp.audit")

TOPIC_EVENTS = "/audit/events"
TOPIC_LOG = "/log"
TOPIC_ROBOT_DESCRIPTION = "/robot_description"
TOPIC_JOINTS_PLAN = "/joint_states/plan"
TOPIC_JOINTS_EXECUTED = "/joint_states/executed"
TOPIC_TF = "/tf"
TOPIC_COM = "/markers/com"
TOPIC_SUPPORT = "/markers/support"

#: Frame prefix of the executed motion in /tf (the plan uses none).
EXECUTED_PREFIX = "executed/"

KIND_OPEN = "audit.open"
KIND_CLOSE = "audit.close"

LOG_LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}

# Marker colours (RGBA in [0, 1]).
_GREEN = {"r": 0.1, "g": 0.75, "b": 0.3, "a": 1.0}
_ORANGE = {"r": 1.0, "g": 0.55, "b": 0.0, "a": 1.0}
_RED = {"r": 0.9, "g": 0.1, "b": 0.1, "a": 1.0}
_BLUE = {"r": 0.15, "g": 0.35, "b": 0.95, "a": 1.0}
_WHITE = {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}
_IDENTITY_POSE = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}

Point2 = Sequence[float]
Point3 = Sequence[float]


class AuditSettings(BaseSettings):
    """Tunables of the audit writer (environment: ``REGRASP_AUDIT_*``)."""

    model_config = SettingsConfigDict(env_prefix="REGRASP_AUDIT_")

    #: Upper bound of one MCAP chunk; a bulk write (plan playback) spans several.
    chunk_size_bytes: int = 64 * 1024
    #: ``none`` keeps the file greppable; ``zstd`` makes it ~5x smaller.
    compression: Literal["none", "zstd"] = "none"
    #: fsync after every call: survives power loss, not only a killed process.
    fsync: bool = False
    #: Rate at which a plan is sampled for playback in Foxglove (the full plan is
    #: in its ``plan`` event at full rate).
    plan_playback_rate_hz: float = 50.0
    #: Height of the support-polygon outlines above the ground (visible over a grid).
    marker_lift_m: float = 0.002
    #: Diameter of the CoM sphere marker.
    com_marker_diameter_m: float = 0.04
    #: Derive Foxglove views (plan playback, executed joint states) from ``record`` payloads.
    auto_visualize: bool = True
    #: Highest rate of /tf for the executed motion (every joint state is still recorded;
    #: the transforms only animate the model). 0 = a transform for every state.
    executed_tf_rate_hz: float = 50.0


class AuditError(RuntimeError):
    """The audit file cannot be written (closed writer, bad input)."""


def _stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // NS_PER_S, "nsec": ns % NS_PER_S}


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (datetime,)):
        return value.isoformat()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot record a value of type {type(value).__name__} in the audit file")


def _v3(p: Sequence[float]) -> dict[str, float]:
    return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])}


def _q(q: Sequence[float]) -> dict[str, float]:
    return {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}


def _entity(entity_id: str, ns: int, **primitives: list) -> dict[str, Any]:
    entity: dict[str, Any] = {
        "timestamp": _stamp(ns),
        "frame_id": WORLD_FRAME,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [],
    }
    for key in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"):
        entity[key] = primitives.get(key, [])
    return entity


def _line(points: Sequence[Point3], color: dict, *, loop: bool, thickness: float = 0.006) -> dict[str, Any]:
    return {
        "type": 1 if loop else 0,
        "pose": _IDENTITY_POSE,
        "thickness": thickness,
        "scale_invariant": False,
        "points": [_v3(p) for p in points],
        "color": color,
        "colors": [],
        "indices": [],
    }


def shrink_polygon(polygon: Sequence[Point2], distance_m: float) -> list[list[float]]:
    """The polygon offset inward by ``distance_m`` (empty if nothing is left)."""
    from shapely.geometry import Polygon

    if len(polygon) < 3 or distance_m <= 0:
        return [list(map(float, p)) for p in polygon]
    inner = Polygon([(float(x), float(y)) for x, y in polygon]).buffer(-distance_m, join_style=2)
    if inner.is_empty or inner.geom_type != "Polygon":
        return []
    coords = list(inner.exterior.coords)[:-1]
    return [[float(x), float(y)] for x, y in coords]


class AuditWriter:
    """Append-only, hash-chained MCAP audit file of one job.

    ``record`` and the helpers return the new chain head (hex SHA-256), which the
    service stores with the job. The writer is thread-safe; every call ends with
    the data on the OS (and on disk with ``settings.fsync``).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        job_id: str,
        *,
        robot_name: str | None = None,
        urdf_text: str | None = None,
        settings: AuditSettings | None = None,
        clock_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        if not job_id:
            raise AuditError("job_id must be a non-empty string")
        self.path = Path(path)
        self.job_id = str(job_id)
        self.robot_name = robot_name
        self.settings = settings or AuditSettings()
        self._clock = clock_ns
        self._lock = threading.RLock()
        self._tree: UrdfTree | None = parse_urdf(urdf_text) if urdf_text else None
        self._stream = open(self.path, "xb")  # never overwrite an audit file
        self._writer = Writer(
            self._stream,
            chunk_size=self.settings.chunk_size_bytes,
            compression=CompressionType.ZSTD if self.settings.compression == "zstd" else CompressionType.NONE,
            enable_crcs=True,
            enable_data_crcs=True,
        )
        self._writer.start(profile="", library=f"regrasp-audit ({CHAIN_FORMAT})")
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._seq = 0
        self._head = GENESIS
        self._closed = False
        self._last_executed_tf_ns: int | None = None
        #: The plan's stance base pose: the floating base stays there (CONTRACT section 3),
        #: so executed states without one are placed with it.
        self._base_pose: list[float] | None = None
        self.record(
            KIND_OPEN,
            {
                "job_id": self.job_id,
                "format": CHAIN_FORMAT,
                "robot": robot_name,
                "created_utc": datetime.now(timezone.utc).isoformat(),
                "has_robot_description": urdf_text is not None,
            },
        )
        if urdf_text:
            self.robot_description(urdf_text)

    # ------------------------------------------------------------------ basics
    @property
    def head(self) -> str:
        """SHA-256 of the last record written (the value to store with the job)."""
        return self._head

    @property
    def records(self) -> int:
        """Number of chain records written so far."""
        return self._seq

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> "AuditWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        if not self._closed:
            self.close()

    def _channel(self, topic: str, schema: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != schema:
                raise AuditError(f"topic {topic} already carries {known[1]}, not {schema}")
            return known[0]
        if schema not in self._schema_ids:
            self._schema_ids[schema] = self._writer.register_schema(
                name=schema, encoding="jsonschema", data=fx.schema_bytes(schema)
            )
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding="json", schema_id=self._schema_ids[schema]
        )
        self._channels[topic] = (channel_id, schema)
        return channel_id

    def _emit(self, topic: str, schema: str, message: dict[str, Any], log_time_ns: int) -> str:
        if self._closed:
            raise AuditError(f"audit file {self.path} is closed")
        if log_time_ns < 0:
            raise AuditError(f"log time must be >= 0 ns, got {log_time_ns}")
        channel_id = self._channel(topic, schema)
        body = dict(message)
        body["audit"] = {"seq": self._seq, "prev": self._head}
        try:
            data = json.dumps(body, separators=(",", ":"), allow_nan=False, default=_json_default).encode("utf-8")
        except ValueError as exc:
            raise AuditError(f"{topic}: payload has a non-finite number (NaN/Inf): {exc}") from exc
        digest = record_digest(self._seq, topic, schema, log_time_ns, log_time_ns, data)
        self._writer.add_message(
            channel_id=channel_id, log_time=log_time_ns, data=data, publish_time=log_time_ns, sequence=self._seq
        )
        self._seq += 1
        self._head = digest
        return digest

    def _commit(self) -> str:
        """Close the open chunk and push it to the OS (and disk if configured)."""
        self._writer.flush()
        if self.settings.fsync:
            os.fsync(self._stream.fileno())
        return self._head

    def _now(self, log_time_ns: int | None) -> int:
        return int(self._clock() if log_time_ns is None else log_time_ns)

    # ----------------------------------------------------------------- events
    def record(self, kind: str, payload: Mapping[str, Any], log_time_ns: int | None = None) -> str:
        """Record one event of the job and a readable /log line; returns the new head.

        ``kind`` names what happened (``state``, ``request``, ``plan``, ``survey``,
        ``approval``, ``gate``, ``dispatch``, ``exec`` ...); ``payload`` is any
        JSON-serialisable mapping (numpy arrays allowed, NaN/Inf refused).
        """
        if not kind or not isinstance(kind, str):
            raise AuditError("event kind must be a non-empty string")
        if not isinstance(payload, Mapping):
            raise AuditError(f"event payload must be a mapping, got {type(payload).__name__}")
        with self._lock:
            ns = self._now(log_time_ns)
            self._emit(
                TOPIC_EVENTS,
                fx.AUDIT_EVENT,
                {"timestamp": _stamp(ns), "job_id": self.job_id, "kind": kind, "payload": dict(payload)},
                ns,
            )
            level = "error" if kind.endswith(("error", "failed", "veto")) else "info"
            self._emit(TOPIC_LOG, fx.LOG, self._log_body(f"{kind}: {_summarise(payload)}", level, ns), ns)
            self._commit()
            if self.settings.auto_visualize:
                self._visualize(payload, ns)
            return self._head

    def _visualize(self, payload: Mapping[str, Any], ns: int) -> None:
        """Foxglove views derived from an event, so callers that only use ``record`` get them too.

        - a plan document (CONTRACT section 3, as the payload or its ``document``/``plan``)
          -> the robot description (looked up by the plan's robot name if none was
          given) and the plan's playback;
        - ``joint_names`` with ``q`` (or ``positions``) in the payload or its ``data``
          -> an executed joint state (``base_pose`` used if present).
        Never raises: the event itself is already recorded.
        """
        try:
            plan = _find_plan(payload)
            if plan is not None:
                if self._tree is None:
                    urdf = _urdf_for((plan.get("robot") or {}).get("name") or self.robot_name)
                    if urdf is not None:
                        self.robot_description(urdf, ns)
                self.plan_playback(plan, ns)
                return
            state = _find_joint_state(payload)
            if state is not None:
                names, q, base = state
                self.joint_state(names, q, source="executed", base_pose=base, log_time_ns=ns)
        except Exception as exc:  # noqa: BLE001 - a view must never lose the audit event
            _log.warning("audit %s: no Foxglove view for an event (%s)", self.job_id, exc)

    def state_change(
        self,
        old: str | None,
        new: str,
        *,
        reason: str | None = None,
        actor: str | None = None,
        log_time_ns: int | None = None,
    ) -> str:
        """A job state transition (``queued -> planning`` ...)."""
        return self.record("state", {"from": old, "to": new, "reason": reason, "actor": actor}, log_time_ns)

    def _log_body(self, message: str, level: str, ns: int) -> dict[str, Any]:
        if level not in LOG_LEVELS:
            raise AuditError(f"unknown log level {level!r}; valid: {', '.join(LOG_LEVELS)}")
        return {
            "timestamp": _stamp(ns),
            "level": LOG_LEVELS[level],
            "message": message,
            "name": f"regrasp/job/{self.job_id}",
            "file": "",
            "line": 0,
        }

    def log(self, message: str, level: str = "info", log_time_ns: int | None = None) -> str:
        """A free-form log line (foxglove.Log on /log)."""
        with self._lock:
            ns = self._now(log_time_ns)
            self._emit(TOPIC_LOG, fx.LOG, self._log_body(str(message), level, ns), ns)
            return self._commit()

    # ------------------------------------------------------------- robot model
    def robot_description(self, urdf_text: str, log_time_ns: int | None = None) -> str:
        """Publish the URDF on /robot_description (Foxglove's 3D panel loads it)."""
        with self._lock:
            self._tree = parse_urdf(urdf_text)
            ns = self._now(log_time_ns)
            self._emit(TOPIC_ROBOT_DESCRIPTION, fx.ROBOT_DESCRIPTION, {"data": urdf_text}, ns)
            return self._commit()

    def _tf_message(
        self,
        positions: Mapping[str, float],
        base_pose: Sequence[float] | None,
        prefix: str,
        ns: int,
    ) -> dict[str, Any] | None:
        transforms = []
        stamp = _stamp(ns)
        if self._tree is not None and base_pose is not None:
            transforms.append(
                {
                    "timestamp": stamp,
                    "parent_frame_id": WORLD_FRAME,
                    "child_frame_id": prefix + self._tree.root,
                    "translation": _v3(base_pose[:3]),
                    "rotation": _q(base_pose[3:7]),
                }
            )
        if self._tree is not None:
            for parent, child, xyz, quat in joint_transforms(self._tree, positions):
                transforms.append(
                    {
                        "timestamp": stamp,
                        "parent_frame_id": prefix + parent,
                        "child_frame_id": prefix + child,
                        "translation": _v3(xyz),
                        "rotation": _q(quat),
                    }
                )
        return {"transforms": transforms} if transforms else None

    def _joint_state_messages(
        self,
        topic: str,
        joint_names: Sequence[str],
        q: Sequence[float],
        base_pose: Sequence[float] | None,
        prefix: str,
        ns: int,
        velocity: Sequence[float] | None = None,
        with_tf: bool = True,
    ) -> None:
        if len(joint_names) != len(q):
            raise AuditError(f"{len(joint_names)} joint names but {len(q)} positions")
        if velocity is not None and len(velocity) != len(q):
            raise AuditError(f"{len(q)} positions but {len(velocity)} velocities")
        if base_pose is not None and len(base_pose) != 7:
            raise AuditError(f"base pose must be [x, y, z, qx, qy, qz, qw], got {len(base_pose)} numbers")
        joints = []
        for i, name in enumerate(joint_names):
            joint: dict[str, Any] = {"name": str(name), "position": float(q[i])}
            if velocity is not None:
                joint["velocity"] = float(velocity[i])
            joints.append(joint)
        self._emit(topic, fx.JOINT_STATES, {"timestamp": _stamp(ns), "joints": joints}, ns)
        if not with_tf:
            return
        positions = {str(n): float(v) for n, v in zip(joint_names, q)}
        tf = self._tf_message(positions, base_pose, prefix, ns)
        if tf is not None:
            self._emit(TOPIC_TF, fx.FRAME_TRANSFORMS, tf, ns)

    def joint_state(
        self,
        joint_names: Sequence[str],
        q: Sequence[float],
        *,
        source: Literal["plan", "executed"] = "executed",
        base_pose: Sequence[float] | None = None,
        velocity: Sequence[float] | None = None,
        log_time_ns: int | None = None,
    ) -> str:
        """One joint state (and its /tf) of the plan or of the executed motion."""
        if source not in ("plan", "executed"):
            raise AuditError(f"joint state source must be 'plan' or 'executed', got {source!r}")
        topic = TOPIC_JOINTS_PLAN if source == "plan" else TOPIC_JOINTS_EXECUTED
        prefix = "" if source == "plan" else EXECUTED_PREFIX
        if base_pose is None:
            base_pose = self._base_pose
        with self._lock:
            ns = self._now(log_time_ns)
            with_tf = True
            rate = self.settings.executed_tf_rate_hz
            if source == "executed" and rate > 0:
                with_tf = self._last_executed_tf_ns is None or ns - self._last_executed_tf_ns >= NS_PER_S / rate
                if with_tf:
                    self._last_executed_tf_ns = ns
            self._joint_state_messages(topic, joint_names, q, base_pose, prefix, ns, velocity, with_tf)
            return self._commit()

    def transforms(
        self,
        transforms: Sequence[tuple[str, str, Sequence[float], Sequence[float]]],
        log_time_ns: int | None = None,
    ) -> str:
        """Arbitrary frame transforms ``(parent, child, [x, y, z], [qx, qy, qz, qw])`` on /tf."""
        with self._lock:
            ns = self._now(log_time_ns)
            stamp = _stamp(ns)
            body = {
                "transforms": [
                    {
                        "timestamp": stamp,
                        "parent_frame_id": str(parent),
                        "child_frame_id": str(child),
                        "translation": _v3(xyz),
                        "rotation": _q(quat),
                    }
                    for parent, child, xyz, quat in transforms
                ]
            }
            self._emit(TOPIC_TF, fx.FRAME_TRANSFORMS, body, ns)
            return self._commit()

    # ---------------------------------------------------------------- markers
    def _support_body(
        self, polygon: Sequence[Point2], shrunk: Sequence[Point2] | None, threshold_m: float | None, ns: int
    ) -> dict[str, Any]:
        z = self.settings.marker_lift_m
        lines = [_line([(p[0], p[1], z) for p in polygon], _GREEN, loop=True)]
        if shrunk is None and threshold_m is not None:
            shrunk = shrink_polygon(polygon, threshold_m)
        if shrunk:
            lines.append(_line([(p[0], p[1], z) for p in shrunk], _ORANGE, loop=True, thickness=0.004))
        label = "support polygon" + (f", threshold {threshold_m * 1000:.0f} mm" if threshold_m is not None else "")
        texts = []
        if len(polygon):
            cx = float(np.mean([p[0] for p in polygon]))
            ymin = float(min(p[1] for p in polygon))
            texts.append(
                {
                    "pose": {"position": {"x": cx, "y": ymin - 0.05, "z": z}, "orientation": _IDENTITY_POSE["orientation"]},
                    "billboard": True,
                    "font_size": 12.0,
                    "scale_invariant": True,
                    "color": _WHITE,
                    "text": label,
                }
            )
        return {"deletions": [], "entities": [_entity("support", ns, lines=lines, texts=texts)]}

    def support_markers(
        self,
        polygon: Sequence[Point2],
        *,
        shrunk: Sequence[Point2] | None = None,
        threshold_m: float | None = None,
        log_time_ns: int | None = None,
    ) -> str:
        """Support polygon (green) and the polygon shrunk by the threshold (orange).

        Pass ``shrunk`` as computed by the planner, or ``threshold_m`` to have it
        computed here (inward offset with mitred corners).
        """
        if len(polygon) < 3:
            raise AuditError(f"a support polygon needs at least 3 vertices, got {len(polygon)}")
        with self._lock:
            ns = self._now(log_time_ns)
            self._emit(TOPIC_SUPPORT, fx.SCENE_UPDATE, self._support_body(polygon, shrunk, threshold_m, ns), ns)
            return self._commit()

    def _com_body(
        self, com: Point3, margin_m: float | None, threshold_m: float | None, trace: Sequence[Point3] | None, ns: int
    ) -> dict[str, Any]:
        ok = margin_m is None or threshold_m is None or margin_m >= threshold_m
        color = _BLUE if ok else _RED
        d = self.settings.com_marker_diameter_m
        spheres = [
            {
                "pose": {"position": _v3(com), "orientation": _IDENTITY_POSE["orientation"]},
                "size": {"x": d, "y": d, "z": d},
                "color": color,
            }
        ]
        ground = (com[0], com[1], self.settings.marker_lift_m)
        lines = [_line([com, ground], color, loop=False, thickness=0.003)]
        if trace:
            lines.append(_line([(p[0], p[1], self.settings.marker_lift_m) for p in trace], _BLUE, loop=False, thickness=0.003))
        texts = []
        if margin_m is not None:
            texts.append(
                {
                    "pose": {"position": _v3((com[0], com[1], com[2] + 0.06)), "orientation": _IDENTITY_POSE["orientation"]},
                    "billboard": True,
                    "font_size": 12.0,
                    "scale_invariant": True,
                    "color": color,
                    "text": f"margin {margin_m * 1000:.1f} mm",
                }
            )
        return {"deletions": [], "entities": [_entity("com", ns, spheres=spheres, lines=lines, texts=texts)]}

    def com_marker(
        self,
        com: Point3,
        *,
        margin_m: float | None = None,
        threshold_m: float | None = None,
        trace: Sequence[Point3] | None = None,
        log_time_ns: int | None = None,
    ) -> str:
        """The CoM as a sphere with a drop line to the ground, its margin, and an optional trace.

        The sphere turns red when ``margin_m`` is below ``threshold_m``.
        """
        if len(com) != 3:
            raise AuditError(f"CoM must be [x, y, z], got {len(com)} numbers")
        with self._lock:
            ns = self._now(log_time_ns)
            self._emit(TOPIC_COM, fx.SCENE_UPDATE, self._com_body(com, margin_m, threshold_m, trace, ns), ns)
            return self._commit()

    # ------------------------------------------------------------ plan preview
    def plan_playback(self, plan: Mapping[str, Any], start_ns: int | None = None) -> str:
        """Sample a solved plan (CONTRACT section 3) for playback in Foxglove.

        Writes the support polygon and its shrunk copy once, then at
        ``settings.plan_playback_rate_hz`` the plan's joint states, /tf and CoM
        marker, at log times ``start_ns + t``. The last point is always included.
        """
        trajectory = plan.get("trajectory") or []
        if not trajectory:
            return self.head
        joint_names = list((plan.get("robot") or {}).get("joint_names") or [])
        base_pose = (plan.get("stance") or {}).get("base_pose")
        if base_pose is not None and len(base_pose) == 7:
            self._base_pose = [float(v) for v in base_pose]
        threshold = plan.get("threshold_m")
        dt = float(plan.get("dt_s") or 0.0)
        rate = self.settings.plan_playback_rate_hz
        stride = max(1, int(round(1.0 / (rate * dt)))) if dt > 0 and rate > 0 else 1
        indices = list(range(0, len(trajectory), stride))
        if indices[-1] != len(trajectory) - 1:
            indices.append(len(trajectory) - 1)
        with self._lock:
            t0 = self._now(start_ns)
            polygon = plan.get("support_polygon") or []
            if len(polygon) >= 3:
                self._emit(TOPIC_SUPPORT, fx.SCENE_UPDATE, self._support_body(polygon, None, threshold, t0), t0)
            trace: list[Point3] = []
            for i in indices:
                point = trajectory[i]
                ns = t0 + int(round(float(point.get("t", i * dt)) * NS_PER_S))
                if joint_names and point.get("q") is not None:
                    self._joint_state_messages(TOPIC_JOINTS_PLAN, joint_names, point["q"], base_pose, "", ns)
                com = point.get("com")
                if com is not None:
                    trace.append(com)
                    self._emit(
                        TOPIC_COM, fx.SCENE_UPDATE, self._com_body(com, point.get("margin_m"), threshold, trace, ns), ns
                    )
            return self._commit()

    # ------------------------------------------------------------------ close
    def close(self, log_time_ns: int | None = None) -> str:
        """Write the closing record and the MCAP summary; returns the final head."""
        with self._lock:
            if self._closed:
                return self._head
            ns = self._now(log_time_ns)
            self._emit(
                TOPIC_EVENTS,
                fx.AUDIT_EVENT,
                {
                    "timestamp": _stamp(ns),
                    "job_id": self.job_id,
                    "kind": KIND_CLOSE,
                    "payload": {"records_before": self._seq},
                },
                ns,
            )
            self._writer.finish()
            self._stream.flush()
            if self.settings.fsync:
                os.fsync(self._stream.fileno())
            self._stream.close()
            self._closed = True
            return self._head


def _summarise(payload: Mapping[str, Any], limit: int = 160) -> str:
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
        return text
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


def _find_plan(payload: Mapping[str, Any]) -> Mapping[str, Any] | None:
    for candidate in (payload, payload.get("document"), payload.get("plan"), payload.get("result")):
        if (
            isinstance(candidate, Mapping)
            and str(candidate.get("schema", "")).startswith("regrasp.plan/")
            and candidate.get("trajectory")
        ):
            return candidate
    return None


def _find_joint_state(payload: Mapping[str, Any]) -> tuple[list[str], list[float], list[float] | None] | None:
    for candidate in (payload, payload.get("data"), payload.get("payload")):
        if not isinstance(candidate, Mapping):
            continue
        names = candidate.get("joint_names")
        q = candidate.get("q", candidate.get("positions"))
        if isinstance(names, (list, tuple)) and isinstance(q, (list, tuple)) and len(names) == len(q) and names:
            base = candidate.get("base_pose")
            return list(names), [float(v) for v in q], list(base) if base is not None else None
    return None


def _urdf_for(robot_name: str | None) -> str | None:
    """The URDF text of a known robot (from the planner's registry), or None."""
    if not robot_name:
        return None
    try:
        from planner.robot.registry import urdf_path

        return urdf_path(str(robot_name)).read_text()
    except Exception as exc:  # noqa: BLE001 - unknown robot: the file simply has no model
        _log.warning("audit: no robot description for %r (%s)", robot_name, exc)
        return None
