"""The dispatcher's vocabulary: its settings, its errors, how an execution ended, and a plan cut into segments.

Part of the dispatcher (:mod:`robot_bridge.dispatcher`); shared by its execution state machine
(:mod:`robot_bridge.dispatch_run`), its controller watch (:mod:`robot_bridge.dispatch_watch`) and its
zenoh I/O (:mod:`robot_bridge.dispatch_io`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Literal

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from schemas.bridge import MAX_SEGMENT_DURATION_S, GateVerdict, TrajectorySegment

from .errors import BridgeError
from .gate import ExecutablePlan
from .signing import Signer, canonical_bytes

#: ``on_event(kind, data)``: every step of an execution, for the service's job record and audit.
EventCallback = Callable[[str, dict[str, Any]], None]


class DispatchSettings(BaseSettings):
    """Pacing and deadlines of one execution (environment prefix ``REGRASP_DISPATCH_``).

    The lookahead is counted in trajectory time; a controller that plays faster than
    real time (the simulator's ``--speed``) needs proportionally more segments ahead.
    """

    model_config = SettingsConfigDict(env_prefix="REGRASP_DISPATCH_", frozen=True, extra="forbid")

    segment_duration_s: float = Field(0.25, gt=0, le=MAX_SEGMENT_DURATION_S,
                                      description="time spanned by one segment's points (the contract allows 1 s; "
                                                  "0.25 s keeps a segment near 20 KB, so it crosses in about a millisecond)")
    lookahead_segments: int = Field(8, ge=1, le=1000, description="segments sent ahead of the one being played (2 s)")
    max_in_flight_segments: int = Field(
        2, ge=1, le=1000,
        description="segments sent but not yet acknowledged, at most: the lookahead fills one acknowledgement (about a "
                    "millisecond) at a time instead of in one burst, whose later segments queued behind the earlier ones "
                    "in the controller's receive path (up to 3 ms for the 9-segment burst of a job's start)",
    )
    in_flight_wait_s: float = Field(
        0.01, gt=0, le=1.0,
        description="once the oldest unacknowledged segment is this old, one more segment goes out every this often "
                    "whatever the window: a late acknowledgement (a stalled peer, a lost segment) must not starve a "
                    "controller that plays the two segments it has in 50 ms (0.25 s segments at 10x), and the lookahead "
                    "must not go out in one burst either (80 segments at 10x overflowed zenoh's transmit queue, whose "
                    "drop-on-congestion then lost segments)",
    )
    poll_period_s: float = Field(0.005, gt=0, le=0.1, description="how often the execution loop looks at its inputs")
    self_stall_s: float = Field(
        0.05, gt=0, le=1.0,
        description="a loss watch that did not run for this long was itself held up (its process starved of the "
                    "CPU or the interpreter): the heartbeat watchdog then counts from when it runs again, since the "
                    "controller's heartbeats that came meanwhile were waiting for the same interpreter. The robot is "
                    "still covered meanwhile: the controller's own dead-man stops it if this process goes quiet")
    resync_s: float = Field(
        1.0, gt=0, le=10.0,
        description="after this process was held up for longer than the watchdog (frozen: the controller's dead-man "
                    "has stopped the robot, and the link may have been dropped and made again), how long the "
                    "controller is given to be heard from (its own report of how the job ended) before it is judged "
                    "lost")
    progress_timeout_s: float = Field(3.0, gt=0, description="no progress report for this long = fault (counted from "
                                                              "the end of a stall longer than the watchdog, if later)")
    resend_after_s: float = Field(0.1, gt=0, description="re-send a segment the controller has not acknowledged by then")
    gap_holdoff_s: float = Field(
        0.02, gt=0, le=1.0,
        description="when the controller refuses a segment for a gap before it, the missing one and those behind it are "
                    "re-sent at once (not after resend_after_s: a fast-playing controller has less than that buffered "
                    "at a job's start); refusals within this time after such a re-send are of copies already on their "
                    "way and start no other",
    )
    max_resends: int = Field(5, ge=0, le=100, description="re-sends of the oldest unacknowledged segment (the controller "
                                                           "drops duplicates); the ones behind it go with it for free")
    ack_timeout_s: float = Field(1.0, gt=0, description="wait for the controller to acknowledge a stop")
    robot_state_event_period_s: float = Field(0.1, gt=0, description="rate of 'robot_state' events (for the audit)")
    state_max_age_s: float = Field(0.5, gt=0, description="a measured state older than this is not used by the gate")
    state_wait_s: float = Field(
        1.0, ge=0, le=10.0,
        description="when a dispatch starts while the controller's token is present but its heartbeat or joint state is "
                    "not fresh, wait this long for fresh ones before refusing: a host that paused the bridge's process "
                    "(a VM's steal, a long collection) leaves both stale for a moment although the controller is fine",
    )
    start_tolerance_rad: float = Field(0.01, gt=0, description="first point vs measured state (sent with each measured "
                                                                 "state: it overrides the gate's own setting)")


class ControllerUnavailableError(BridgeError, RuntimeError):
    """No controller is alive, or its state is unknown: nothing was started (HTTP 409)."""


class BusyError(BridgeError, RuntimeError):
    """Another execution is running on this dispatcher."""


class NoSigningKeyError(BridgeError, RuntimeError):
    """The dispatcher has no signing key: the controller would refuse every command, so nothing is sent (HTTP 409)."""


class SignedSegment:
    """One segment's canonical JSON, split around its ``expires_at`` so that a send only adds the expiry and signs.

    Keys sort ``dt_s``, ``expires_at``, ...: the canonical bytes are ``prefix + repr(expires_at) + suffix``."""

    __slots__ = ("seq", "prefix", "suffix")

    def __init__(self, seg: TrajectorySegment):
        doc = seg.model_dump(mode="json", exclude={"sig"})
        doc["expires_at"] = 0.0
        body = canonical_bytes(doc)
        marker = b'"expires_at":0.0,'
        i = body.index(marker) + len(b'"expires_at":')
        self.seq = seg.seq
        self.prefix, self.suffix = body[:i], body[i + len(b"0.0"):]

    def wire(self, signer: Signer, expires_at: float) -> bytes:
        body = self.prefix + repr(float(expires_at)).encode() + self.suffix
        return body[:-1] + b',"sig":"' + signer.signature(body).encode("ascii") + b'"}'


@dataclass
class ExecutionResult:
    """How an execution ended: ``succeeded``, ``aborted`` (stopped, lost, fault) or ``rejected`` (gate veto)."""

    status: Literal["succeeded", "aborted", "rejected"]
    reason: str
    verdict: GateVerdict | None = None
    last_index: int | None = None
    segments_sent: int = 0
    duration_s: float = 0.0
    details: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"status": self.status, "reason": self.reason, "verdict": self.verdict.model_dump(mode="json") if self.verdict else None,
                "last_index": self.last_index, "segments_sent": self.segments_sent, "duration_s": self.duration_s,
                "details": self.details}


def split_segments(plan: dict[str, Any] | ExecutablePlan, job_id: str, plan_sha256: str, first_seq: int,
                   segment_duration_s: float = MAX_SEGMENT_DURATION_S) -> list[TrajectorySegment]:
    """The plan's trajectory cut into consecutive segments of at most ``segment_duration_s``.

    ``plan`` is a plan document or the fields the gate decoded from its bytes (:class:`ExecutablePlan`)."""
    if isinstance(plan, ExecutablePlan):
        dt, names = float(plan.dt_s), list(plan.robot.joint_names)
        qs, holding = [p.q for p in plan.trajectory], [p.holding for p in plan.trajectory]
        mass = float(plan.object.mass_kg)
    else:
        dt, names = float(plan["dt_s"]), list(plan["robot"]["joint_names"])
        qs, holding = [p["q"] for p in plan["trajectory"]], [p["holding"] for p in plan["trajectory"]]
        mass = float(plan["object"]["mass_kg"]) if isinstance(plan.get("object"), dict) and "mass_kg" in plan["object"] else None
    per = max(1, int(math.floor(segment_duration_s / dt + 1e-9)) + 1)  # points spanning at most the duration
    starts = list(range(0, len(qs), per))
    return [
        TrajectorySegment(
            job_id=job_id, plan_sha256=plan_sha256, seq=first_seq + k, segment_index=k, segment_count=len(starts),
            joint_names=names, dt_s=dt, t_from_start=start * dt, first_index=start,
            points=qs[start:start + per], holding=holding[start:start + per], object_mass_kg=mass,
        )
        for k, start in enumerate(starts)
    ]
