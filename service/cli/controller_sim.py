"""``regrasp controller-sim``: run the simulated controller peer (docs/contract.md section 6).

The stance posture is computed here, in the CLI layer, with the planner's stance
solver (or read from ``--initial-q FILE.json``); ``robot_bridge`` itself never
imports the planner. Prints one JSON line ``{"ready": true, ...}`` on stdout once
the peer is up, so scripts and tests can wait for it.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
from pathlib import Path

import click

from .common import describe, fail


def _stance_posture(robot: str, stance: str) -> tuple[list[str], list[float]]:
    from planner.api.catalogue import StanceError, solve_stance
    from planner.api.robots import load_robot

    try:
        model = load_robot(robot)
        st = solve_stance(model, stance)
    except (StanceError, ValueError) as exc:
        fail(str(exc))
    return list(model.joint_names), st.q.tolist()


def _stance_support(robot: str, stance: str, spec: dict) -> tuple[list[float], dict[str, bool]]:
    """The stance's base pose and which feet carry the robot (the physics plant stands on those soles)."""
    from planner.api.catalogue import StanceError, solve_stance
    from planner.api.robots import load_robot

    try:
        st = solve_stance(load_robot(robot), stance).result().model_dump()
    except (StanceError, ValueError) as exc:
        fail(str(exc))
    side_of = {spec["feet"][side]["frame"]: side for side in ("left", "right")}
    return list(st["base_pose"]), {side_of[f["frame"]]: bool(f["in_contact"]) for f in st["feet"] if f["frame"] in side_of}


def _physics_plant(robot: str, stance: str, spec: dict, names: list[str], q: list[float], object_mass_kg: float | None,
                   stabilizer: bool, push_n: float, push_s: float, effort_scale: float, limits: dict[str, float]):
    """The MuJoCo twin, settled in the start posture (docs/physics.md)."""
    import numpy as np
    from pydantic import ValidationError

    from robot_bridge.physics.model import TwinModelError
    from robot_bridge.physics.plant import physics_plant
    from robot_bridge.physics.settings import FaultLimits, StabilizerSettings, TwinSettings

    base, in_contact = _stance_support(robot, stance, spec)
    try:
        settings = TwinSettings(stabilizer=StabilizerSettings(enabled=stabilizer), faults=FaultLimits(**limits))
        return physics_plant(robot, names, np.array(q), np.array(base), in_contact, settings,
                             object_mass_kg=object_mass_kg, push_n=push_n, push_s=push_s, effort_scale=effort_scale)
    except (TwinModelError, ValidationError, ValueError) as exc:
        fail(f"--plant physics: {exc}")


def _initial_q_file(path: str) -> tuple[list[str], list[float]]:
    try:
        doc = json.loads(Path(path).read_text())
        names, q = doc["joint_names"], doc["q"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        fail(f"--initial-q {path}: expected a JSON object with 'joint_names' and 'q': {exc}")
    if len(names) != len(q):
        fail(f"--initial-q {path}: {len(names)} joint names for {len(q)} values")
    return list(names), [float(v) for v in q]


@click.command("controller-sim")
@click.option("--robot", "robot", default="hrp5p", show_default=True, help="Robot model (URDF, limits).")
@click.option("--robot-id", default=None, help="ROBOT in the key expressions (default: the robot name).")
@click.option("--stance", default="upright", show_default=True, help="Stance whose posture the controller starts in.")
@click.option("--initial-q", type=click.Path(exists=True, dir_okay=False), default=None,
              help="JSON {joint_names, q}: start in this posture instead of solving the stance.")
@click.option("--speed", type=float, default=1.0, show_default=True,
              help="Play trajectories K times faster than real time (physics: simulated time up to K x the wall clock; "
                   "the overrun is reported when the machine cannot keep up, no step is skipped).")
@click.option("--states-per-motion-s", type=click.FloatRange(1.0, 2000.0), default=None,
              help="Measured joint states published per second of motion (default 60; CONTRACT 7 asks for 50).")
@click.option("--plant", type=click.Choice(["kinematic", "physics"]), default="kinematic", show_default=True,
              help="kinematic: replay the commands; physics: the MuJoCo twin (measured joints, state/balance, faults).")
@click.option("--object-mass-kg", type=click.FloatRange(0.0, 100.0), default=None,
              help="Physics: the mass a closing hand takes on (its CoM at the TCP); default the planned object's mass "
                   "the segments carry. Another mass is a payload mismatch the twin's wrist sensors notice.")
@click.option("--no-stabilizer", is_flag=True, help="Physics: the twin's stabilizer off.")
@click.option("--push-n", type=click.FloatRange(-5000.0, 5000.0), default=0.0, show_default=True,
              help="Fault (physics): a horizontal force on the base (N, +x) from the first job's playback.")
@click.option("--push-s", type=click.FloatRange(0.0, 60.0), default=0.5, show_default=True,
              help="Fault (physics): how long the push lasts (simulated s).")
@click.option("--effort-scale", type=click.FloatRange(0.01, 1.0), default=1.0, show_default=True,
              help="Fault (physics): scale every joint's effort limit from the first job's playback (weaker joints "
                   "saturate).")
@click.option("--foot-tilt-limit-rad", type=click.FloatRange(0.001, 1.5), default=None,
              help="Physics: the foot tilt that is a fault (default 0.05 rad).")
@click.option("--foot-lift-limit-mm", type=click.FloatRange(1.0, 1000.0), default=None,
              help="Physics: the sole lift that is a fault (default 10 mm).")
@click.option("--start-buffer-ms", type=click.FloatRange(0.0, 10_000.0), default=None,
              help="Wall-clock time of motion held before playback starts, or the whole job, or after waiting as long "
                   "(default: the settings' start_buffer_s).")
@click.option("--listen", "listen", multiple=True, help="zenoh endpoint to listen on (repeatable); default tcp/127.0.0.1:7447.")
@click.option("--connect", "connect", multiple=True, help="zenoh endpoint to connect to (repeatable).")
@click.option("--drop-rate", type=click.FloatRange(0.0, 1.0), default=0.0, show_default=True,
              help="Fault: share of incoming commands dropped.")
@click.option("--delay-ms", type=click.FloatRange(0.0, 10_000.0), default=0.0, show_default=True,
              help="Fault: delay before each command is handled (ms).")
@click.option("--crash-after", type=click.IntRange(min=1), default=None,
              help="Fault: hard exit right after accepting N segments.")
@click.option("--freeze-heartbeat-after-s", type=click.FloatRange(min=0.0), default=None,
              help="Fault: stop the heartbeat T s after the first accepted segment, staying alive otherwise.")
@click.option("--heartbeat-period-s", type=click.FloatRange(min=0.001), default=None, help="Heartbeat period (default 0.05 s).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the drop decisions.")
@click.option("--trusted-key", type=click.Path(dir_okay=False), default=None,
              help="PEM public key of the dispatcher (dispatcher.pub); without one only cmd/stop is obeyed "
                   "(default: REGRASP_BRIDGE_TRUSTED_KEY).")
@click.option("--watchdog-ms", type=click.FloatRange(min=1.0, max=5000.0), default=None,
              help="Dead-man: stop when no dispatcher heartbeat came for this long (default 250 ms).")
def controller_sim(robot: str, robot_id: str | None, stance: str, initial_q: str | None, speed: float,
                   states_per_motion_s: float | None, plant: str,
                   object_mass_kg: float | None, no_stabilizer: bool, push_n: float, push_s: float, effort_scale: float,
                   foot_tilt_limit_rad: float | None, foot_lift_limit_mm: float | None, start_buffer_ms: float | None, listen: tuple[str, ...],
                   connect: tuple[str, ...], drop_rate: float, delay_ms: float, crash_after: int | None,
                   freeze_heartbeat_after_s: float | None, heartbeat_period_s: float | None, seed: int,
                   trusted_key: str | None, watchdog_ms: float | None) -> None:
    """Run a simulated controller that speaks the bridge protocol until interrupted."""
    from pydantic import ValidationError

    from robot_bridge.controller_process import run_controller
    from robot_bridge.controller_settings import ControllerSimSettings, limits_from_urdf
    from robot_bridge.robot_files import RobotFilesError, robot_files
    from robot_bridge.settings import BridgeSettings

    try:
        files = robot_files(robot)
    except RobotFilesError as exc:
        fail(str(exc))
    names, q = _initial_q_file(initial_q) if initial_q else _stance_posture(robot, stance)
    overrides: dict = {"robot_id": robot_id or robot, "listen": list(listen) or ["tcp/127.0.0.1:7447"], "connect": list(connect)}
    if heartbeat_period_s is not None:
        overrides["heartbeat_period_s"] = heartbeat_period_s
        overrides["watchdog_timeout_s"] = max(0.25, 5 * heartbeat_period_s)
    if watchdog_ms is not None:
        overrides["watchdog_timeout_s"] = watchdog_ms / 1000.0
    if trusted_key is not None:
        overrides["trusted_key"] = trusted_key
    try:
        bridge = BridgeSettings(**overrides)
        if bridge.trusted_key is not None:
            from robot_bridge.signing import KeyFileError, load_public_key

            try:
                load_public_key(bridge.trusted_key)
            except KeyFileError as exc:
                fail(f"--trusted-key: {exc}")
        buffer = {} if start_buffer_ms is None else {"start_buffer_s": start_buffer_ms / 1000.0}
        if states_per_motion_s is not None:
            buffer["joint_states_per_motion_s"] = states_per_motion_s
        sim = ControllerSimSettings(speed=speed, plant=plant, **buffer, drop_rate=drop_rate, delay_ms=delay_ms, crash_after=crash_after,
                                    freeze_heartbeat_after_s=freeze_heartbeat_after_s, seed=seed,
                                    stance=stance)
        limits = limits_from_urdf(str(files.urdf), names)
    except (ValidationError, ValueError) as exc:
        fail(describe(exc, {"speed": "--speed", "drop_rate": "--drop-rate", "delay_ms": "--delay-ms",
                            "crash_after": "--crash-after", "seed": "--seed", "start_buffer_s": "--start-buffer-ms",
                            "heartbeat_period_s": "--heartbeat-period-s", "watchdog_timeout_s": "--watchdog-ms",
                            "freeze_heartbeat_after_s": "--freeze-heartbeat-after-s", "robot_id": "--robot-id"}))

    import numpy as np

    twin = None
    if plant == "physics":
        fault_limits = {k: v for k, v in (("foot_tilt_rad", foot_tilt_limit_rad),
                                          ("foot_lift_m", None if foot_lift_limit_mm is None else foot_lift_limit_mm / 1000))
                        if v is not None}
        twin = _physics_plant(robot, stance, files.spec, names, q, object_mass_kg, not no_stabilizer, push_n, push_s,
                              effort_scale, fault_limits)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())

    def ready(ctl) -> None:
        click.echo(json.dumps({"ready": True, "robot_id": bridge.robot_id, "listen": bridge.listen, "connect": bridge.connect,
                               "speed": speed, "plant": plant, "joints": len(names), "trusted_key": bool(bridge.trusted_key),
                               "watchdog_s": bridge.watchdog_timeout_s}))
        sys.stdout.flush()

    try:
        run_controller(bridge, sim, names, np.array(q), limits, on_ready=ready, stop=stop, plant=twin)
    except Exception as exc:  # zenoh cannot listen (port taken, bad endpoint): say so
        fail(f"controller-sim failed: {exc}", code=1)
