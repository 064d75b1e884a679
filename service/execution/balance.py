"""The robot's balance as its controller reports it (``state/balance``, the physics plant; CONTRACT 6).

A zenoh peer of the service's own, on the bridge's endpoints, keeps the recent samples (for the console's live CoP
trace) and hands them to listeners (an execution records them in its job's events, hence the audit's
``/robot/balance``). Telemetry only: nothing here commands the robot, and a controller without a physics plant
simply publishes none.
"""

from __future__ import annotations

import collections
import json
import logging
import threading
from typing import Any, Callable

log = logging.getLogger("regrasp.execution")

#: Samples kept for the console (10 s at the controller's 50 Hz).
KEPT_SAMPLES = 500


class BalanceWatch:
    """Subscribes to ``regrasp/ROBOT/state/balance``; ``recent(after)`` gives what came since a stamp."""

    def __init__(self) -> None:
        from robot_bridge.settings import BridgeSettings, Keys
        from robot_bridge.zenoh_session import open_session

        settings = BridgeSettings()
        self.robot_id = settings.robot_id
        self._samples: collections.deque[dict[str, Any]] = collections.deque(maxlen=KEPT_SAMPLES)
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
            self._samples.append(doc)
            listeners = list(self._listeners)
        for fn in listeners:
            try:
                fn(doc)
            except Exception:  # noqa: BLE001 - a listener's fault never reaches zenoh's thread
                log.exception("balance listener failed")

    def recent(self, after: float | None = None) -> list[dict[str, Any]]:
        """The kept samples with ``stamp`` after ``after`` (all when None), oldest first."""
        with self._lock:
            return [s for s in self._samples if after is None or float(s.get("stamp", 0.0)) > after]

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
