"""The simulated controller's process: its interpreter and scheduling set up, the peer run until stopped."""

from __future__ import annotations

import sys
import threading
from typing import Callable

import numpy as np

from .controller_settings import ControllerSimSettings, JointLimits
from .controller_sim import ControllerSim
from .plant import Plant
from .process_tuning import freeze_startup_objects, raise_thread_priority, use_realtime_scheduling
from .settings import BridgeSettings
from .signing import Verifier


def run_controller(bridge: BridgeSettings, sim: ControllerSimSettings, joint_names: list[str], q0: np.ndarray,
                   limits: JointLimits, on_ready: Callable[[ControllerSim], None] | None = None,
                   stop: threading.Event | None = None, plant: Plant | None = None) -> None:
    """Run a controller until ``stop`` is set (or forever); the CLI's entry point.

    Without ``bridge.trusted_key`` the controller obeys only cmd/stop (every other command is refused)."""
    sys.setswitchinterval(sim.switch_interval_s)
    # Raised before zenoh opens: its runtime threads inherit this thread's priority.
    raise_thread_priority(bridge.thread_nice)
    use_realtime_scheduling(bridge.realtime_priority)
    verifier = Verifier.from_file(bridge.trusted_key) if bridge.trusted_key is not None else None
    ctl = ControllerSim(bridge, sim, joint_names, q0, limits, verifier=verifier, plant=plant)
    ctl.start()
    freeze_startup_objects()
    try:
        if on_ready is not None:
            on_ready(ctl)
        while not (stop.wait(0.2) if stop is not None else ctl.wait(0.2)):
            pass
    finally:
        ctl.close()
