"""The robot's balance as its controller reports it (``state/balance``, the physics plant; CONTRACT 6).

A zenoh peer of the service's own, on the bridge's endpoints, hands every sample to its listeners (an execution
records them in its job's events, hence the console's live CoP trace and the audit's ``/robot/balance``) and keeps
when the last one came (``/healthz``'s ``balance_age_s``: whether the stream reaches the service before a
dispatch). Telemetry only: nothing here commands the robot, and a controller without a physics plant simply
publishes none.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from typing import Any, Callable

log = logging.getLogger("regrasp.execution")


class BalanceWatch:
    """Subscribes to ``regrasp/ROBOT/state/balance``; ``listen(fn)`` hands on each sample."""

    def __init__(self) -> None:
        from robot_bridge.settings import BridgeSettings, Keys
        from robot_bridge.zenoh_session import open_session

        settings = BridgeSettings()
        self.robot_id = settings.robot_id
        self._last_at: float | None = None  # this process's monotonic clock at the last sample
        self._listeners: list[Callable[[dict[str, Any]], None]] = []
        self._lock = threading.Lock()
        self._session = open_session(settings)
        self._sub = self._session.declare_subscriber(Keys(settings.robot_id).balance, self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        try:
            doc = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        if not isinstance(doc, dict):
            return
        with self._lock:
            self._last_at = time.monotonic()
            listeners = list(self._listeners)
        for fn in listeners:
            try:
                fn(doc)
            except Exception:  # noqa: BLE001 - a listener's fault never reaches zenoh's thread
                log.exception("balance listener failed")

    def last_sample_age_s(self) -> float | None:
        """Seconds since the last sample reached this peer; None when none has."""
        with self._lock:
            return None if self._last_at is None else time.monotonic() - self._last_at

    def listen(self, fn: Callable[[dict[str, Any]], None]) -> Callable[[], None]:
        """Call ``fn`` with every sample from now; returns the function that stops it."""
        with self._lock:
            self._listeners.append(fn)

        def stop() -> None:
            with self._lock:
                if fn in self._listeners:
                    self._listeners.remove(fn)
        return stop

    def close(self) -> None:
        try:
            self._session.close()
        except Exception:  # noqa: BLE001
            pass


def start_balance_watch() -> BalanceWatch | None:
    """The watch on the bridge's endpoints, or None when no zenoh peer can be opened (the service still runs)."""
    try:
        return BalanceWatch()
    except Exception as exc:  # noqa: BLE001 - telemetry is optional; dispatch does not depend on it
        log.warning("robot balance telemetry unavailable (%s)", exc)
        return None
