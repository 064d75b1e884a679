"""Fixtures of the bridge tests: a real controller-sim process and real zenoh peers on loopback."""

from __future__ import annotations

import json
import os
import selectors
import socket
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from .plans import build_plan, stance_state

READY_TIMEOUT_S = 30.0
REPO = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class ControllerProcess:
    proc: subprocess.Popen
    endpoint: str
    robot_id: str
    lines: list[str] = field(default_factory=list)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=5)

    def terminate(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)


@pytest.fixture(scope="session")
def initial_q_file(tmp_path_factory) -> str:
    names, q, _ = stance_state()
    path = tmp_path_factory.mktemp("bridge") / "initial_q.json"
    path.write_text(json.dumps({"joint_names": names, "q": q}))
    return str(path)


@pytest.fixture
def spawn_controller(initial_q_file):
    """Start ``regrasp controller-sim`` processes on free loopback ports; all are ended after the test."""
    started: list[ControllerProcess] = []

    def spawn(*flags: str, speed: float = 4.0) -> ControllerProcess:
        port = free_port()
        robot_id = f"t{uuid.uuid4().hex[:10]}"
        endpoint = f"tcp/127.0.0.1:{port}"
        cmd = [sys.executable, "-m", "service.cli.main", "controller-sim", "--robot-id", robot_id, "--initial-q", initial_q_file,
               "--listen", endpoint, "--speed", str(speed), *flags]
        proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        ctl = ControllerProcess(proc, endpoint, robot_id)
        started.append(ctl)
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + READY_TIMEOUT_S
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                raise RuntimeError(f"controller-sim exited {proc.returncode}: {proc.stderr.read()}")
            if sel.select(timeout=0.1):
                line = proc.stdout.readline()
                ctl.lines.append(line)
                if line.startswith("{") and json.loads(line).get("ready"):
                    return ctl
        raise RuntimeError("controller-sim did not become ready in time")

    yield spawn
    for ctl in started:
        ctl.terminate()


@dataclass
class Spy:
    """A zenoh peer that records everything on cmd/trajectory and cmd/stop."""

    session: object
    endpoint: str
    trajectory: list[dict] = field(default_factory=list)
    stops: list[dict] = field(default_factory=list)

    def peers(self) -> list[str]:
        return [str(z) for z in self.session.info.peers_zid()]


@pytest.fixture
def spy_factory():
    import zenoh

    from robot_bridge.settings import BridgeSettings, Keys
    from robot_bridge.zenoh_session import open_session

    spies: list[Spy] = []

    def make(robot_id: str) -> Spy:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        session = open_session(BridgeSettings(robot_id=robot_id, listen=[endpoint], connect=[]))
        spy = Spy(session, endpoint)
        keys = Keys(robot_id)
        lock = threading.Lock()

        def on_traj(sample: zenoh.Sample) -> None:
            with lock:
                spy.trajectory.append(json.loads(sample.payload.to_bytes()))

        def on_stop(sample: zenoh.Sample) -> None:
            with lock:
                spy.stops.append(json.loads(sample.payload.to_bytes()))

        spy._subs = [session.declare_subscriber(keys.trajectory, on_traj), session.declare_subscriber(keys.stop, on_stop)]
        spies.append(spy)
        return spy

    yield make
    for spy in spies:
        spy.session.close()


@pytest.fixture
def bridge(spawn_controller, spy_factory):
    """(controller, dispatcher, spy) wired on loopback; the dispatcher connects to both peers."""
    from robot_bridge.dispatcher import Dispatcher, DispatchSettings
    from robot_bridge.settings import BridgeSettings

    made = []

    def make(*flags: str, speed: float = 4.0, dispatch: DispatchSettings | None = None, dispatcher_cls=Dispatcher):
        ctl = spawn_controller(*flags, speed=speed)
        spy = spy_factory(ctl.robot_id)
        disp = dispatcher_cls(BridgeSettings(robot_id=ctl.robot_id, connect=[ctl.endpoint, spy.endpoint]), dispatch)
        made.append(disp)
        assert disp.wait_for_controller(10.0), disp.controller_problem()
        deadline = time.monotonic() + 5.0
        while disp.zid() not in spy.peers() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert disp.zid() in spy.peers(), "the spy is not connected to the dispatcher"
        return ctl, disp, spy

    yield make
    for d in made:
        d.close()


def approval_for(plan: dict, ttl_s: float = 300.0) -> tuple[str, datetime]:
    from schemas.plan import plan_sha256

    return plan_sha256(plan), datetime.now(timezone.utc) + timedelta(seconds=ttl_s)


@pytest.fixture(scope="session")
def arm_plan() -> dict:
    """A valid 1.6 s plan: the right shoulder pitches 0.3 rad forward and back... (one cosine move)."""
    return build_plan({"RSP": -0.3}, duration_s=1.5)


@pytest.fixture(scope="session")
def long_plan() -> dict:
    """A valid 3.1 s plan (4 segments) for faults that must hit mid-execution."""
    return build_plan({"RSP": -0.5, "LSP": -0.3}, duration_s=3.0)
