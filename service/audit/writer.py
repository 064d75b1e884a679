"""AuditWriter: one MCAP file per job, hash-chained, zstd-compressed, readable in Foxglove.

Layout of a file (all channels JSON-encoded, schema names Foxglove knows; docs/audit.md):

=======================  ========================  =====================================
topic                    schema                    what
=======================  ========================  =====================================
/audit/events            regrasp.audit.Event       every state change, request, plan,
                                                   survey, approval, gate verdict,
                                                   dispatched segment (``record``)
/log                     foxglove.Log              a readable line per event, its level
                                                   by severity (:mod:`.severity`)
/robot_description       std_msgs/String           the URDF; Foxglove's 3D panel loads it
/plan/joint_states       foxglove.JointStates      the plan, sampled for playback
/plan/tf                 foxglove.FrameTransforms  world -> root link and every joint
/plan/markers/...        foxglove.SceneUpdate      support polygon, scene (tables, planned
                                                   paths), CoM, ZMP, object
/plan/stability          regrasp.plan.Sample       margin, ZMP margin, effort per sample
/robot/joint_states      foxglove.JointStates      the robot state echoed back
/robot/balance           regrasp.robot.Balance     the physics plant's CoP, margin, foot forces, tilt
/robot/tf                foxglove.FrameTransforms  the same, frames under ``executed/``
=======================  ========================  =====================================

Every message is one link of the hash chain (:mod:`service.audit.chain`), logged at
the time of the event it records when the caller gives it. After each call the open
chunk is closed and the stream flushed, so a writer killed with SIGKILL leaves a file
that :func:`service.audit.verify.verify` reads up to its last complete call (exit
code 2, "unfinished"). A writer can start by carrying over the records of such a file
(``AuditWriter(..., carried=...)``), so that one file holds the job's whole chain.
"""

from __future__ import annotations

import hashlib
import logging
import os
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Literal, Mapping, Sequence

from mcap.writer import CompressionType, Writer

from . import foxglove_schemas as fx
from . import markers as mk
from .chain import CHAIN_FORMAT, GENESIS, record_digest
from .encoding import RawJson, dumps, stamp
from .joints import joint_states_body, tf_body
from .layout import LAYOUT_ATTACHMENT, LAYOUT_MEDIA_TYPE, layout_bytes

from .executed import ControllerClock, ExecutedPlan, measured_samples

# Re-exported: importers of service.audit.writer use these names.
from .markers import shrink_polygon  # noqa: F401
from .payloads import find_balance, find_joint_state, find_plan, urdf_for
from .playback import Playback, plan_messages
from .settings import AuditError, AuditSettings
from .severity import level_of, summarise
from .topics import (
    EXECUTED_PREFIX,
    KIND_CLOSE,
    KIND_OPEN,
    LOG_LEVELS,
    NS_PER_S,
    TOPIC_COM,
    TOPIC_EVENTS,
    TOPIC_JOINTS_EXECUTED,
    TOPIC_JOINTS_PLAN,
    TOPIC_LOG,
    TOPIC_PLAN_TF,
    TOPIC_ROBOT_BALANCE,
    TOPIC_ROBOT_COP,
    TOPIC_ROBOT_DESCRIPTION,
    TOPIC_ROBOT_TF,
    TOPIC_SUPPORT,
    TOPIC_TF,
)
from .urdf_frames import UrdfTree, parse_urdf

_log = logging.getLogger("regrasp.audit")

__all__ = ["AuditError", "AuditSettings", "AuditWriter", "RawJson", "shrink_polygon", "EXECUTED_PREFIX", "KIND_CLOSE",
           "KIND_OPEN", "LOG_LEVELS", "NS_PER_S", "TOPIC_COM", "TOPIC_EVENTS", "TOPIC_JOINTS_EXECUTED",
           "TOPIC_JOINTS_PLAN", "TOPIC_LOG", "TOPIC_ROBOT_DESCRIPTION", "TOPIC_SUPPORT", "TOPIC_TF"]

Point2 = Sequence[float]
Point3 = Sequence[float]


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
        carried: Sequence[Any] | None = None,
        log_time_ns: int | None = None,
    ) -> None:
        """Open a new file at ``path`` (never an existing one).

        ``carried``: the verified records of a file a restart cut short (``verify(...,
        keep_raw=True).raw`` up to the stored head), written first and unchanged, so the chain
        goes on in this file; the open record is then theirs, not a new one.
        """
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
        #: The plan's stance base pose: the floating base stays there (the plan format),
        #: so executed states without one are placed with it.
        self._base_pose: list[float] | None = None
        #: The execution's timeline: the controller's clock on the file's, and the plan replayed on it.
        self._controller_clock = ControllerClock()
        self._executed_plan: ExecutedPlan | None = None
        layout = layout_bytes() if self.settings.attach_layout else None
        if carried:
            self._carry(carried)
        else:
            ns = self._now(log_time_ns)
            open_payload: dict[str, Any] = {
                "job_id": self.job_id,
                "format": CHAIN_FORMAT,
                "robot": robot_name,
                "created_utc": datetime.now(timezone.utc).isoformat(),
                "has_robot_description": urdf_text is not None,
            }
            if layout is not None:
                open_payload["layout"] = {"attachment": LAYOUT_ATTACHMENT,
                                          "sha256": hashlib.sha256(layout).hexdigest()}
            self.record(KIND_OPEN, open_payload, ns)
            if urdf_text:
                self.robot_description(urdf_text, ns)
        if layout is not None:
            t = self._now(log_time_ns)
            self._writer.add_attachment(create_time=t, log_time=t, name=LAYOUT_ATTACHMENT,
                                        media_type=LAYOUT_MEDIA_TYPE, data=layout)
            self._commit()

    def _carry(self, carried: Sequence[Any]) -> None:
        """Write the records of a cut file unchanged (same seq, times and bytes), then go on from its head."""
        from schemas.fast_json import loads

        for rec in carried:
            if rec.index != self._seq:
                raise AuditError(f"carried record #{rec.index} out of order (expected #{self._seq})")
            channel_id = self._channel(rec.topic, rec.schema)
            self._writer.add_message(channel_id=channel_id, log_time=rec.log_time_ns, data=rec.data,
                                     publish_time=rec.publish_time_ns, sequence=rec.index)
            self._seq += 1
            self._head = rec.digest
            if rec.topic == TOPIC_ROBOT_DESCRIPTION:
                try:
                    self._tree = parse_urdf(loads(rec.data)["data"])
                except Exception:  # noqa: BLE001 - the views only
                    pass
            elif rec.topic == TOPIC_EVENTS and b'"regrasp.plan/' in rec.data:
                plan = find_plan((loads(rec.data).get("payload") or {}))
                base = ((plan or {}).get("stance") or {}).get("base_pose")
                if isinstance(base, list) and len(base) == 7:
                    self._base_pose = [float(v) for v in base]
        self._commit()

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
            data = fx.schema_bytes(schema) if schema in fx.SCHEMAS else b""
            self._schema_ids[schema] = self._writer.register_schema(name=schema, encoding="jsonschema", data=data)
        channel_id = self._writer.register_channel(topic=topic, message_encoding="json",
                                                   schema_id=self._schema_ids[schema])
        self._channels[topic] = (channel_id, schema)
        return channel_id

    def _emit(self, topic: str, schema: str, message: Mapping[str, Any], log_time_ns: int,
              publish_time_ns: int | None = None) -> str:
        if self._closed:
            raise AuditError(f"audit file {self.path} is closed")
        publish_time_ns = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        if log_time_ns < 0 or publish_time_ns < 0:
            raise AuditError(f"log and publish times must be >= 0 ns, got {log_time_ns} and {publish_time_ns}")
        channel_id = self._channel(topic, schema)
        body = dict(message)
        body["audit"] = {"seq": self._seq, "prev": self._head}
        try:
            data = dumps(body)
        except ValueError as exc:
            raise AuditError(f"{topic}: payload has a non-finite number (NaN/Inf): {exc}") from exc
        digest = record_digest(self._seq, topic, schema, log_time_ns, publish_time_ns, data)
        self._writer.add_message(
            channel_id=channel_id, log_time=log_time_ns, data=data, publish_time=publish_time_ns, sequence=self._seq
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
        JSON-serialisable mapping (numpy arrays allowed, NaN/Inf refused; a
        :class:`RawJson` value goes in as its text). ``log_time_ns``: when the event
        happened (Unix ns); the writer's clock when not given.
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
                {"timestamp": stamp(ns), "job_id": self.job_id, "kind": kind, "payload": dict(payload)},
                ns,
            )
            view = {k: v for k, v in payload.items() if not isinstance(v, RawJson)}
            level = level_of(kind, view)
            self._emit(TOPIC_LOG, fx.LOG, self._log_body(f"{kind}: {summarise(view)}", level, ns), ns)
            self._commit()
            if self.settings.auto_visualize:
                self._visualize(payload, ns)
            return self._head

    def _visualize(self, payload: Mapping[str, Any], ns: int) -> None:
        """Foxglove views derived from an event, so callers that only use ``record`` get them too.

        - a plan document (``regrasp.plan/1``, as the payload or its ``document``/``plan``)
          -> the robot description (looked up by the plan's robot name if none was
          given) and the plan's playback;
        - ``joint_names`` with ``q`` (or ``positions``) in the payload or its ``data``
          -> a joint state of the robot (``base_pose`` used if present).
        Never raises: the event itself is already recorded.
        """
        try:
            plan = find_plan(payload)
            if plan is not None:
                if self._tree is None:
                    urdf = urdf_for((plan.get("robot") or {}).get("name") or self.robot_name)
                    if urdf is not None:
                        self.robot_description(urdf, ns)
                self.plan_playback(plan, ns)
                replay = self.settings.model_copy(update={"plan_playback_rate_hz": self.settings.executed_plan_rate_hz})
                self._executed_plan = ExecutedPlan(Playback(plan, replay, self._tree))
                return
            measured = measured_samples(payload)
            data = payload.get("data") if isinstance(payload.get("data"), Mapping) else payload
            names = data.get("joint_names") if isinstance(data, Mapping) else None
            if measured and isinstance(names, (list, tuple)) and names:
                self._measured(list(names), measured, ns, data.get("base_pose"))
                return
            balance = find_balance(payload)
            if balance is not None:
                self._emit(TOPIC_ROBOT_BALANCE, fx.ROBOT_BALANCE, {"timestamp": stamp(ns), **balance}, ns)
                if isinstance(balance.get("cop_x"), (int, float)) and isinstance(balance.get("cop_y"), (int, float)):
                    inside = not isinstance(balance.get("cop_margin_m"), (int, float)) or balance["cop_margin_m"] >= 0
                    body = mk.cop_body((balance["cop_x"], balance["cop_y"]), inside, ns,
                                       self.settings.zmp_marker_diameter_m, self.settings.marker_lift_m)
                    self._emit(TOPIC_ROBOT_COP, fx.SCENE_UPDATE, body, ns)
                self._commit()
                return
            state = find_joint_state(payload)
            if state is not None:
                names, q, base = state
                self.joint_state(names, q, source="executed", base_pose=base, log_time_ns=ns)
        except Exception as exc:  # noqa: BLE001 - a view must never lose the audit event
            _log.warning("audit %s: no Foxglove view for an event (%s)", self.job_id, exc)

    def _measured(self, names: list[str], samples: list[dict[str, Any]], reported_ns: int,
                  base_pose: Sequence[float] | None) -> None:
        """Measured joint states at the controller's measurement times, and the plan replayed up to them."""
        for sample in samples:
            q = sample.get("q")
            if not isinstance(q, (list, tuple)) or len(q) != len(names):
                continue
            at = self._controller_clock.to_ns(float(sample["stamp"]), reported_ns)
            self.joint_state(names, [float(v) for v in q], source="executed", base_pose=base_pose, log_time_ns=at,
                             publish_time_ns=at)
            index = sample.get("index")
            if self._executed_plan is not None and isinstance(index, int):
                with self._lock:
                    for topic, schema, body, t in self._executed_plan.advance(index, at):
                        self._emit(topic, schema, body, t)
                    self._commit()

    def state_change(self, old: str | None, new: str, *, reason: str | None = None, actor: str | None = None,
                     log_time_ns: int | None = None) -> str:
        """A job state transition (``queued -> planning`` ...)."""
        return self.record("state", {"from": old, "to": new, "reason": reason, "actor": actor}, log_time_ns)

    def _log_body(self, message: str, level: str, ns: int) -> dict[str, Any]:
        if level not in LOG_LEVELS:
            raise AuditError(f"unknown log level {level!r}; valid: {', '.join(LOG_LEVELS)}")
        return {"timestamp": stamp(ns), "level": LOG_LEVELS[level], "message": message,
                "name": f"regrasp/job/{self.job_id}", "file": "", "line": 0}

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

    def joint_state(
        self,
        joint_names: Sequence[str],
        q: Sequence[float],
        *,
        source: Literal["plan", "executed"] = "executed",
        base_pose: Sequence[float] | None = None,
        velocity: Sequence[float] | None = None,
        log_time_ns: int | None = None,
        publish_time_ns: int | None = None,
    ) -> str:
        """One joint state (and its transforms) of the plan (/plan/) or as the robot reported it (/robot/).

        ``publish_time_ns``: when it was measured (the controller's time on the file's clock), if known.
        """
        if source not in ("plan", "executed"):
            raise AuditError(f"joint state source must be 'plan' or 'executed', got {source!r}")
        plan = source == "plan"
        if base_pose is None:
            base_pose = self._base_pose
        with self._lock:
            ns = self._now(log_time_ns)
            body = joint_states_body(joint_names, q, velocity, ns)
            with_tf = True
            rate = self.settings.executed_tf_rate_hz
            if not plan and rate > 0:
                with_tf = self._last_executed_tf_ns is None or ns - self._last_executed_tf_ns >= NS_PER_S / rate
            tf = tf_body(self._tree, {str(n): float(v) for n, v in zip(joint_names, q)}, base_pose,
                         "" if plan else EXECUTED_PREFIX, ns) if with_tf else None
            self._emit(TOPIC_JOINTS_PLAN if plan else TOPIC_JOINTS_EXECUTED, fx.JOINT_STATES, body, ns, publish_time_ns)
            if tf is not None:
                if not plan:
                    self._last_executed_tf_ns = ns
                self._emit(TOPIC_PLAN_TF if plan else TOPIC_ROBOT_TF, fx.FRAME_TRANSFORMS, tf, ns, publish_time_ns)
            return self._commit()

    def transforms(self, transforms: Sequence[tuple[str, str, Sequence[float], Sequence[float]]],
                   log_time_ns: int | None = None) -> str:
        """Arbitrary frame transforms ``(parent, child, [x, y, z], [qx, qy, qz, qw])`` on /tf."""
        with self._lock:
            ns = self._now(log_time_ns)
            t = stamp(ns)
            body = {"transforms": [{"timestamp": t, "parent_frame_id": str(parent), "child_frame_id": str(child),
                                    "translation": mk.v3(xyz), "rotation": mk.quat(rot)}
                                   for parent, child, xyz, rot in transforms]}
            self._emit(TOPIC_TF, fx.FRAME_TRANSFORMS, body, ns)
            return self._commit()

    # ---------------------------------------------------------------- markers
    def support_markers(self, polygon: Sequence[Point2], *, shrunk: Sequence[Point2] | None = None,
                        threshold_m: float | None = None, log_time_ns: int | None = None) -> str:
        """Support polygon (green) and the polygon shrunk by the threshold (orange).

        Pass ``shrunk`` as computed by the planner, or ``threshold_m`` to have it
        computed here (inward offset with mitred corners).
        """
        if len(polygon) < 3:
            raise AuditError(f"a support polygon needs at least 3 vertices, got {len(polygon)}")
        with self._lock:
            ns = self._now(log_time_ns)
            body = mk.support_body(polygon, shrunk, threshold_m, ns, self.settings.marker_lift_m)
            self._emit(TOPIC_SUPPORT, fx.SCENE_UPDATE, body, ns)
            return self._commit()

    def com_marker(self, com: Point3, *, margin_m: float | None = None, threshold_m: float | None = None,
                   trace: Sequence[Point3] | None = None, log_time_ns: int | None = None) -> str:
        """The CoM as a sphere with a drop line to the ground and its margin (red below ``threshold_m``).

        ``trace``: a ground path to draw with it, as given (the writer never accumulates one).
        """
        if len(com) != 3:
            raise AuditError(f"CoM must be [x, y, z], got {len(com)} numbers")
        with self._lock:
            ns = self._now(log_time_ns)
            body = mk.com_body(com, margin_m, threshold_m, trace, ns, self.settings.com_marker_diameter_m,
                               self.settings.marker_lift_m)
            self._emit(TOPIC_COM, fx.SCENE_UPDATE, body, ns)
            return self._commit()

    # ------------------------------------------------------------ plan preview
    def plan_playback(self, plan: Mapping[str, Any], start_ns: int | None = None) -> str:
        """The plan's playback under /plan/ (:mod:`service.audit.playback`), at log times ``start_ns + t``."""
        if not plan.get("trajectory"):
            return self.head
        base_pose = (plan.get("stance") or {}).get("base_pose")
        if base_pose is not None and len(base_pose) == 7:
            self._base_pose = [float(v) for v in base_pose]
        with self._lock:
            t0 = self._now(start_ns)
            for topic, schema, body, ns in plan_messages(plan, t0, self.settings, self._tree):
                self._emit(topic, schema, body, ns)
            return self._commit()

    # ------------------------------------------------------------------ close
    def close(self, log_time_ns: int | None = None) -> str:
        """Write the closing record and the MCAP summary; returns the final head."""
        with self._lock:
            if self._closed:
                return self._head
            ns = self._now(log_time_ns)
            self._emit(TOPIC_EVENTS, fx.AUDIT_EVENT, {"timestamp": stamp(ns), "job_id": self.job_id,
                                                      "kind": KIND_CLOSE, "payload": {"records_before": self._seq}}, ns)
            self._writer.finish()
            self._stream.flush()
            if self.settings.fsync:
                os.fsync(self._stream.fileno())
            self._stream.close()
            self._closed = True
            return self._head
