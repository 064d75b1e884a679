"""The robot bridge as the service sees it: a small interface in front of robot_bridge.dispatcher.

Until ``robot_bridge.dispatcher`` is installed (or when it cannot start), the
service uses :class:`NoBridge`, for which no controller is ever alive, so
dispatch answers 409 instead of pretending to move a robot.
"""

from __future__ import annotations

import importlib
import importlib.util
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
    def controller_alive(self) -> bool: ...

    def execute(self, plan: dict[str, Any], *, job_id: str, approved_sha256: str, approval_expires_at: Any,
                threshold_m: float, on_event: Callable[[str, dict[str, Any]], None],
                stop_event: threading.Event) -> Outcome: ...

    def stop(self, job_id: str) -> None: ...

    def close(self) -> None: ...


class NoBridge:
    """Stands in while no robot bridge is installed: no controller is alive."""

    reason = "the robot bridge (robot_bridge.dispatcher) is not installed"

    def controller_alive(self) -> bool:
        return False

    def execute(self, plan: dict[str, Any], **kwargs: Any) -> Outcome:
        return Outcome("aborted", "no controller is alive")

    def stop(self, job_id: str) -> None:
        return None

    def close(self) -> None:
        return None


class DispatcherBridge:
    """Adapter over ``robot_bridge.dispatcher.Dispatcher``: normalises its result to :class:`Outcome`."""

    def __init__(self, dispatcher: Any) -> None:
        self._d = dispatcher

    @property
    def reason(self) -> str | None:
        """Why no controller is usable (the dispatcher's own words), for the 409's detail."""
        problem = getattr(self._d, "controller_problem", None)
        try:
            return problem() if callable(problem) else None
        except Exception:  # noqa: BLE001
            return None

    def controller_alive(self) -> bool:
        try:
            return bool(self._d.controller_alive())
        except Exception:  # noqa: BLE001 - a broken bridge means no controller
            log.exception("controller_alive() failed")
            return False

    def execute(self, plan: dict[str, Any], **kwargs: Any) -> Outcome:
        res = self._d.execute(plan, **kwargs)
        status = getattr(res, "status", None) or (res.get("status") if isinstance(res, dict) else None)
        reason = getattr(res, "reason", None) if not isinstance(res, dict) else res.get("reason")
        verdict = getattr(res, "verdict", None) if not isinstance(res, dict) else res.get("verdict")
        if verdict is not None and not isinstance(verdict, dict):
            verdict = _to_dict(verdict)
        details = res.to_dict() if hasattr(res, "to_dict") else None
        if isinstance(details, dict):
            details = {k: v for k, v in details.items() if k not in ("status", "reason", "verdict")}
        if status not in ("succeeded", "aborted", "rejected"):
            return Outcome("aborted", f"the bridge returned an unknown status {status!r}", verdict, details)
        return Outcome(status, reason, verdict, details)

    def stop(self, job_id: str) -> None:
        self._d.stop(job_id)

    def close(self) -> None:
        self._d.close()


def _to_dict(obj: Any) -> dict[str, Any]:
    if hasattr(obj, "model_dump"):
        try:
            return dict(obj.model_dump(mode="json"))
        except Exception:  # noqa: BLE001
            pass
    for attr in ("_asdict", "to_dict"):
        if hasattr(obj, attr):
            try:
                return dict(getattr(obj, attr)())
            except Exception:  # noqa: BLE001
                pass
    if hasattr(obj, "__dict__"):
        return {k: v for k, v in vars(obj).items() if not k.startswith("_")}
    return {"value": repr(obj)}


def make_bridge(robot: str = "hrp5p") -> Bridge:
    """The real dispatcher if robot_bridge.dispatcher is installed and starts, else :class:`NoBridge`."""
    if importlib.util.find_spec("robot_bridge.dispatcher") is None:
        return NoBridge()
    try:
        module = importlib.import_module("robot_bridge.dispatcher")
        dispatcher_cls = getattr(module, "Dispatcher")
        try:
            dispatcher = dispatcher_cls(robot=robot)
        except TypeError:
            dispatcher = dispatcher_cls()
        return DispatcherBridge(dispatcher)
    except Exception as exc:  # noqa: BLE001 - the service must still plan without a bridge
        log.warning("robot bridge unavailable (%s); dispatch will answer 409", exc)
        bridge = NoBridge()
        bridge.reason = f"the robot bridge failed to start: {exc}"
        return bridge
