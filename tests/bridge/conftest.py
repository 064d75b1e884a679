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
from typing import Callable, Iterator, TypeVar

import pytest

from .plans import build_plan, stance_state

T = TypeVar("T")

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


@dataclass(frozen=True)
class KeyPair:
    private: str
    public: str


@pytest.fixture(scope="session")
def key_pair(tmp_path_factory) -> KeyPair:
    """The dispatcher's signing key and the controller's trusted key, made for this test session."""
    from robot_bridge.signing import generate_keys

    private, public = generate_keys(tmp_path_factory.mktemp("keys"))
    return KeyPair(str(private), str(public))


@pytest.fixture(scope="session")
def initial_q_file(tmp_path_factory) -> str:
    names, q, _ = stance_state()
    path = tmp_path_factory.mktemp("bridge") / "initial_q.json"
    path.write_text(json.dumps({"joint_names": names, "q": q}))
    return str(path)


def start_controller(initial_q_file: str, *flags: str, speed: float = 4.0, trusted_key: str | None = None,
                     watchdog_s: float | None = None, plant: str = "kinematic") -> ControllerProcess:
    """Start ``regrasp controller-sim`` on a free loopback port and wait (bounded) for its ready line.

    ``trusted_key``: the dispatcher's public key (without one the controller obeys only stop);
    ``watchdog_s``: its dead-man (default the production 0.25 s); ``plant``: kinematic, or physics (the MuJoCo
    twin, always at speed 1: the robot in the loop is a physical one)."""
    if plant == "physics":
        flags, speed = (*flags, "--plant", "physics"), 1.0
    port = free_port()
    robot_id = f"t{uuid.uuid4().hex[:10]}"
    endpoint = f"tcp/127.0.0.1:{port}"
    cmd = [sys.executable, "-m", "service.cli.main", "controller-sim", "--robot-id", robot_id, "--initial-q", initial_q_file,
           "--listen", endpoint, "--speed", str(speed), *flags]
    if trusted_key is not None:
        cmd += ["--trusted-key", trusted_key]
    if watchdog_s is not None:
        cmd += ["--watchdog-ms", str(watchdog_s * 1000.0)]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    ctl = ControllerProcess(proc, endpoint, robot_id)
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
    ctl.kill()
    raise RuntimeError("controller-sim did not become ready in time")


def closing_factory(make: Callable[..., T], close: Callable[[T], object]) -> Iterator[Callable[..., T]]:
    """The body of a factory fixture: yields ``make``, remembering what it made, and closes each after the test."""
    made: list[T] = []

    def factory(*args, **kwargs) -> T:
        made.append(make(*args, **kwargs))
        return made[-1]

    yield factory
    for thing in made:
        close(thing)


def plant_of(request) -> str:
    """The plant a test module runs its controllers with: its ``plant`` fixture's, else kinematic."""
    return request.getfixturevalue("plant") if "plant" in request.fixturenames else "kinematic"


@pytest.fixture
def spawn_controller(initial_q_file, key_pair, request):
    """Start controller-sim processes trusting the session's key; all are ended after the test."""
    plant = plant_of(request)

    def make(*flags, speed=4.0, trusted_key=key_pair.public, watchdog_s=None):
        return start_controller(initial_q_file, *flags, speed=speed, trusted_key=trusted_key, watchdog_s=watchdog_s,
                                plant=plant)

    yield from closing_factory(make, ControllerProcess.terminate)


@dataclass
class Spy:
    """A zenoh peer that records everything on cmd/trajectory and cmd/stop, with the QoS each sample arrived with."""

    session: object
    endpoint: str
    trajectory: list[dict] = field(default_factory=list)
    stops: list[dict] = field(default_factory=list)
    trajectory_qos: list[tuple] = field(default_factory=list)  # (priority, express, congestion_control) per sample
    stop_qos: list[tuple] = field(default_factory=list)

    def peers(self) -> list[str]:
        return [str(z) for z in self.session.info.peers_zid()]


def make_spy(robot_id: str) -> Spy:
    """A spy peer listening on a free port (the dispatcher connects to it)."""
    import zenoh

    from robot_bridge.settings import BridgeSettings, Keys
    from robot_bridge.zenoh_session import open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(BridgeSettings(robot_id=robot_id, listen=[endpoint], connect=[]))
    spy = Spy(session, endpoint)
    keys = Keys(robot_id)
    lock = threading.Lock()

    def qos(sample: zenoh.Sample) -> tuple:
        return sample.priority, sample.express, sample.congestion_control

    def on_traj(sample: zenoh.Sample) -> None:
        with lock:
            spy.trajectory.append(json.loads(sample.payload.to_bytes()))
            spy.trajectory_qos.append(qos(sample))

    def on_stop(sample: zenoh.Sample) -> None:
        with lock:
            spy.stops.append(json.loads(sample.payload.to_bytes()))
            spy.stop_qos.append(qos(sample))

    spy._subs = [session.declare_subscriber(keys.trajectory, on_traj), session.declare_subscriber(keys.stop, on_stop)]
    return spy


#: Watchdog of the tests that do not test the watchdog: the CI machine's host pauses the whole VM
#: at times for over a second (1.14 and 1.50 s seen), which would abort unrelated cases. A killed
#: controller is still noticed at once (its liveliness token goes with its socket).
RELAXED_WATCHDOG_S = 5.0


def connect_dispatcher(ctl: ControllerProcess, spy: Spy, dispatch=None, dispatcher_cls=None,
                       watchdog_timeout_s: float = RELAXED_WATCHDOG_S, signing_key: str | None = None, **kwargs):
    """A dispatcher connected to the controller and to the spy, signing with ``signing_key``; waits (bounded)
    for both."""
    from robot_bridge.dispatcher import Dispatcher
    from robot_bridge.settings import BridgeSettings

    cls = dispatcher_cls or Dispatcher
    disp = cls(BridgeSettings(robot_id=ctl.robot_id, connect=[ctl.endpoint, spy.endpoint],
                              watchdog_timeout_s=watchdog_timeout_s, signing_key=signing_key), dispatch, **kwargs)
    assert disp.wait_for_controller(10.0), disp.controller_problem()
    deadline = time.monotonic() + 5.0
    while disp.zid() not in spy.peers() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert disp.zid() in spy.peers(), "the spy is not connected to the dispatcher"
    return disp


@pytest.fixture
def spy_factory():
    yield from closing_factory(make_spy, lambda spy: spy.session.close())


@pytest.fixture
def bridge(spawn_controller, spy_factory, key_pair):
    """(controller, dispatcher, spy) wired on loopback; the dispatcher connects to both peers and signs with the
    session's key, which the controller trusts. Both watchdogs are relaxed unless a test names one: ``watchdog_timeout_s``
    is the dispatcher's, ``controller_watchdog_s`` the controller's dead-man (default: the same)."""
    made = []

    def make(*flags: str, speed: float = 4.0, dispatch=None, dispatcher_cls=None, watchdog_timeout_s=RELAXED_WATCHDOG_S,
             controller_watchdog_s=None, **kwargs):
        ctl = spawn_controller(*flags, speed=speed, watchdog_s=controller_watchdog_s or watchdog_timeout_s)
        spy = spy_factory(ctl.robot_id)
        disp = connect_dispatcher(ctl, spy, dispatch, dispatcher_cls, watchdog_timeout_s, key_pair.private, **kwargs)
        made.append(disp)
        return ctl, disp, spy

    yield make
    for d in made:
        d.close()


@pytest.fixture(scope="module")
def shared_bridge(initial_q_file, key_pair, request):
    """One controller, spy and dispatcher for tests that never move the robot (the vetoes)."""
    ctl = start_controller(initial_q_file, trusted_key=key_pair.public, watchdog_s=RELAXED_WATCHDOG_S,
                           plant=plant_of(request))
    spy = make_spy(ctl.robot_id)
    disp = connect_dispatcher(ctl, spy, signing_key=key_pair.private)
    yield ctl, disp, spy
    disp.close()
    spy.session.close()
    ctl.terminate()


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
