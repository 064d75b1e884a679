"""The robot bridge as the service sees it: a small interface in front of robot_bridge.dispatcher.

When the dispatcher cannot start (zenoh fails to open), the service uses
:class:`NoBridge`, for which no controller is ever alive, so dispatch answers
409 instead of pretending to move a robot.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from typing import Any, Callable, Protocol

log = logging.getLogger("regrasp.bridge")


@dataclass
class Outcome:
    """How an execution ended: status 'succeeded' | 'aborted' | 'rejected', with the reason and the gate verdict."""

    status: str
    reason: str | None = None
    verdict: dict[str, Any] | None = None
    details: dict[str, Any] | None = None


class Bridge(Protocol):
    #: Why commands cannot be signed (no or unreadable signing key), or None when they can.
    signing_problem: str | None

    def controller_alive(self) -> bool: ...

    def execute(self, plan: dict[str, Any] | str | bytes, *, job_id: str, approved_sha256: str, approval_expires_at: Any,
                threshold_m: float | None, on_event: Callable[[str, dict[str, Any]], None],
                stop_event: threading.Event) -> Outcome: ...

    def stop(self, job_id: str) -> None: ...

    def close(self) -> None: ...


class NoBridge:
    """Stands in when the robot bridge cannot start: no controller is alive."""

    reason = "the robot bridge is not running"
    signing_problem: str | None = None
    robot_id: str | None = None

    def controller_alive(self) -> bool:
        return False

    def measured_state(self) -> dict[str, Any] | None:
        return None

    def execute(self, plan: dict[str, Any] | str | bytes, **kwargs: Any) -> Outcome:
        return Outcome("aborted", "no controller is alive")

    def stop(self, job_id: str) -> None:
        return None

    def close(self) -> None:
        return None


class DispatcherBridge:
    """Adapter over ``robot_bridge.dispatcher.Dispatcher``: its result as an :class:`Outcome`."""

    def __init__(self, dispatcher: Any, signing_problem: str | None = None) -> None:
        self._d = dispatcher
        self.signing_problem = signing_problem if signing_problem is not None else (
            None if getattr(dispatcher, "signer", None) is not None
            else "no signing key is configured (REGRASP_BRIDGE_SIGNING_KEY; make one with 'regrasp keys generate DIR')")

    @property
    def robot_id(self) -> str:
        return self._d.settings.robot_id

    @property
    def on_controller_return(self) -> Any:
        return self._d.on_controller_return

    @on_controller_return.setter
    def on_controller_return(self, callback: Any) -> None:
        self._d.on_controller_return = callback

    def measured_state(self) -> dict[str, Any] | None:
        """The controller's latest joint state (``state/joints``) as a dict, or None when it is unknown or stale."""
        js = self._d.measured_state()
        return None if js is None else js.model_dump(mode="json")

    @property
    def reason(self) -> str | None:
        """Why no controller is usable (the dispatcher's own words), for the 409's detail."""
        return self._d.controller_problem()

    def controller_alive(self) -> bool:
        try:
            return bool(self._d.controller_alive())
        except Exception:  # noqa: BLE001 - a broken bridge means no controller
            log.exception("controller_alive() failed")
            return False

    def execute(self, plan: dict[str, Any] | str | bytes, **kwargs: Any) -> Outcome:
        """``plan`` is the plan dict or its canonical JSON text/bytes (hashed as they are by the gate)."""
        res = self._d.execute(plan, **kwargs).to_dict()
        status, reason, verdict = res.pop("status"), res.pop("reason"), res.pop("verdict")
        return Outcome(status, reason, verdict, res)

    def stop(self, job_id: str) -> None:
        self._d.stop(job_id)

    def close(self) -> None:
        self._d.close()


def make_bridge(policy: Any = None) -> Bridge:
    """The zenoh dispatcher of robot_bridge, or :class:`NoBridge` when it cannot start (dispatch then answers 409).

    The dispatcher runs in a process of its own (``robot_bridge.dispatcher_process``): its heartbeat and
    watchdog then never wait for the interpreter behind the API's threads. A signing key that cannot be
    read does not stop the service: it plans, and dispatch answers 409 saying why. ``policy``: the site's
    safety policy (:class:`schemas.policy.SafetyPolicy`) the bridge's gate enforces; default the built-in one."""
    from robot_bridge.dispatcher_process import DispatcherProcess
    from robot_bridge.settings import BridgeSettings
    from robot_bridge.signing import KeyFileError, Signer

    try:
        settings = BridgeSettings()
        problem = None
        if settings.signing_key is not None:
            try:
                Signer.from_file(settings.signing_key)
            except KeyFileError as exc:
                problem = f"the signing key cannot be used: {exc}"
                log.warning("robot bridge: %s; dispatch will answer 409", problem)
                settings = settings.model_copy(update={"signing_key": None})
        return DispatcherBridge(DispatcherProcess(settings, policy=policy), problem)
    except Exception as exc:  # noqa: BLE001 - the service must still plan without a bridge
        log.warning("robot bridge unavailable (%s); dispatch will answer 409", exc)
        bridge = NoBridge()
        bridge.reason = f"the robot bridge failed to start: {exc}"
        return bridge
