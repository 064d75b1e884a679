"""The dispatcher's I/O: its zenoh session, the command publishers, and the signed bytes it puts on them.

Part of the dispatcher (:mod:`robot_bridge.dispatcher`). Commands go out at real-time priority, express,
drop on congestion (:func:`robot_bridge.zenoh_session.control_publisher`); every one is signed with the
dispatcher's Ed25519 key where it has one and carries ``expires_at``. Telemetry comes in through the
callbacks given to :meth:`DispatcherIO.subscribe`, on zenoh's threads.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable

import zenoh

from schemas.bridge import Stop

from .process_tuning import bridge_priority
from .settings import BridgeSettings, Keys
from .signing import Signer, canonical_bytes
from .zenoh_session import control_publisher, open_session


class DispatcherIO:
    """One zenoh peer session of the dispatcher, with its command publishers."""

    def __init__(self, settings: BridgeSettings, signer: Signer | None):
        self.settings = settings
        self.signer = signer
        self.keys = Keys(settings.robot_id)
        # zenoh's runtime threads start with the session and inherit this thread's priority for their lives (their
        # callbacks take the interpreter lock on the bridge's path); the calling thread gets its own back afterwards.
        with bridge_priority(settings.thread_nice, settings.realtime_priority):
            self.session: zenoh.Session | None = open_session(settings)
        s = self.session
        self.pub_traj = control_publisher(s, self.keys.trajectory)
        self.pub_stop = control_publisher(s, self.keys.stop)
        self.pub_heartbeat = control_publisher(s, self.keys.command_heartbeat)
        self._subs: list[Any] = []

    def subscribe(self, on_alive: Callable[[zenoh.Sample], None], on_heartbeat: Callable[[zenoh.Sample], None],
                  on_joints: Callable[[zenoh.Sample], None], on_exec: Callable[[zenoh.Sample], None]) -> None:
        """Follow the controller: its liveliness token (with history), heartbeat, joint state and exec status."""
        s, k = self.session, self.keys
        self._subs = [
            s.liveliness().declare_subscriber(k.alive, on_alive, history=True),
            s.declare_subscriber(k.heartbeat, on_heartbeat),
            s.declare_subscriber(k.joints, on_joints),
            s.declare_subscriber(k.exec, on_exec),
        ]

    def zid(self) -> str:
        """This peer's zenoh id (for diagnostics and tests)."""
        return str(self.session.info.zid()) if self.session is not None else ""

    # ------------------------------------------------------------------ commands
    def put_segment(self, wire: bytes) -> None:
        """Put one signed segment on ``cmd/trajectory`` (the execution state machine's only way out)."""
        self.pub_traj.put(wire)

    def put_heartbeat(self, msg: dict[str, Any]) -> None:
        """Put one dispatcher heartbeat on ``cmd/heartbeat``, signed when a key is there."""
        self.pub_heartbeat.put(self.signer.encode(msg) if self.signer is not None else canonical_bytes(msg))

    def stop_bytes(self, job_id: str | None, reason: str) -> bytes:
        """A stop, signed when a key is there (a controller obeys it unsigned too)."""
        now = time.monotonic()
        msg = Stop(job_id=job_id, reason=reason, stamp=now, expires_at=time.time() + self.settings.segment_expiry_s)
        doc = msg.model_dump(mode="json", exclude={"sig"})
        if self.signer is None:
            return canonical_bytes(doc)
        return self.signer.encode(doc)

    def send_stop(self, job_id: str | None, reason: str, repeats: int | None = None) -> float:
        """Publish ``cmd/stop`` now, and again ``stop_repeats - 1`` times from a thread of its own.

        Returns the ``time.monotonic()`` at which the first stop was published."""
        n = repeats if repeats is not None else self.settings.stop_repeats
        sent_at = time.monotonic()
        self.pub_stop.put(self.stop_bytes(job_id, reason))
        if n > 1:
            def again() -> None:
                for _ in range(n - 1):
                    time.sleep(self.settings.stop_repeat_period_s)
                    try:
                        self.pub_stop.put(self.stop_bytes(job_id, reason))
                    except Exception:
                        return
            threading.Thread(target=again, name="stop-repeat", daemon=True).start()
        return sent_at

    def close(self) -> None:
        """Undeclare the subscribers and close the session (idempotent)."""
        if self.session is None:
            return
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
        self.session.close()
        self.session = None

