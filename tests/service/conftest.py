"""Fixtures of the service tests: real `regrasp serve` processes on 127.0.0.1 with test tokens.

The servers run the test job handlers of svc_test_handlers.py (real CPU work
with progress and cancel polling), so these tests do not depend on the planner.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import httpx
import pytest

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from svc_test_handlers import HANDLERS  # noqa: E402

TOKENS = {
    "tok-alice-planner": {"user": "alice", "roles": ["planner"]},
    "tok-dave-planner-approver": {"user": "dave", "roles": ["planner", "approver"]},
    "tok-bob-approver-operator": {"user": "bob", "roles": ["approver", "operator"]},
    "tok-carol-approver": {"user": "carol", "roles": ["approver"]},
    "tok-admin-admin": {"user": "admin", "roles": ["admin"]},
}
TOKEN = {entry["user"]: tok for tok, entry in TOKENS.items()}
STARTUP_TIMEOUT_S = 60.0
#: The states an execution ends in, as the dispatch tests wait for them.
END_STATES = {"succeeded", "aborted", "rejected", "failed"}
#: How long a spawned simulated controller may take to be heard (a first run compiles kernels).
CONTROLLER_UP_TIMEOUT_S = 60.0
#: The first bytes of every MCAP file (an audit download starts with them).
MCAP_MAGIC = b"\x89MCAP0\r\n"


def inline_scenario(**changes: Any) -> dict[str, Any]:
    """A small valid inline scenario (a box moved along a table), with ``changes`` applied."""
    doc: dict[str, Any] = {
        "schema": "regrasp.scenario/1", "name": "inline", "robot": "hrp5p", "stance": "upright",
        "object": {"shape": "box", "size": [0.2, 0.2, 0.2], "mass_kg": 2.0},
        "start_pose": [0.5, 0.0, 0.8, 0, 0, 0, 1], "goal_pose": [0.5, 0.2, 0.8, 0, 0, 0, 1],
        "tables": [{"name": "t", "pose": [0.5, 0.0, 0.35, 0, 0, 0, 1], "size": [0.6, 1.0, 0.7]}],
    }
    doc.update(changes)
    return doc


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


#: zenoh robot id of the test servers' bridge, so no other test's controller is ever seen.
BRIDGE_ROBOT_ID = "svctest"
BRIDGE_WATCHDOG_S = 2.0
#: The zenoh lease both peers of a service test announce. A lease shorter than the relaxed watchdog would
#: still drop the controller's token on a 1 s stall of either process (CI aborted a real-planner execution
#: with "liveliness token ... is absent"), so the watchdog would not be the binding check these tests relax. The bridge's own tests keep the 1 s default lease; SIGKILL closes the link at once.
BRIDGE_LEASE_S = 3.0


_KEYS: dict[str, str] = {}


def bridge_keys() -> dict[str, str]:
    """The dispatcher's key pair of this test session (``private``, ``public`` PEM paths), made on first use."""
    if not _KEYS:
        import tempfile

        from robot_bridge.signing import generate_keys

        private, public = generate_keys(tempfile.mkdtemp(prefix="regrasp-keys-"))
        _KEYS.update(private=str(private), public=str(public))
    return _KEYS


def start_controller_sim(data_dir: Path, port: int, speed: float, **settings: Any) -> subprocess.Popen[bytes]:
    """`regrasp controller-sim` of the test servers' robot id, listening on ``port``, trusting the session's key,
    its dead-man as relaxed as the servers' watchdog; its log in ``data_dir``.

    ``settings`` become its ``REGRASP_*`` environment (e.g. ``bridge_lease_s="6"``).
    """
    log = open(data_dir / "controller-sim.log", "ab")
    env = dict(os.environ)
    env["REGRASP_BRIDGE_LEASE_S"] = str(BRIDGE_LEASE_S)
    env["REGRASP_BRIDGE_WATCHDOG_TIMEOUT_S"] = str(BRIDGE_WATCHDOG_S)
    env["REGRASP_BRIDGE_TRUSTED_KEY"] = bridge_keys()["public"]
    env.update({f"REGRASP_{key.upper()}": str(value) for key, value in settings.items()})
    return subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", "controller-sim", "--robot-id", BRIDGE_ROBOT_ID,
         "--listen", f"tcp/127.0.0.1:{port}", "--speed", str(speed)],
        cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)


def wait_health(srv: "Server", proc: subprocess.Popen[bytes], timeout_s: float, ready: Callable[[dict], bool],
                what: str) -> None:
    """Poll ``/healthz`` until ``ready(health)``; fail if the simulated controller ``proc`` exits (with its log's
    tail) or ``timeout_s`` passes (saying ``what`` never happened, and the last health)."""
    deadline = time.monotonic() + timeout_s
    while not ready(health := httpx.get(srv.url + "/healthz", timeout=5).json()):
        assert proc.poll() is None, (srv.data_dir / "controller-sim.log").read_text()[-2000:]
        assert time.monotonic() < deadline, f"{what} (last health: {health})"
        time.sleep(0.1)


def wait_controller_alive(srv: "Server", proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    """Wait until the server's bridge sees the simulated controller ``proc``; fail if it exits or never shows."""
    wait_health(srv, proc, timeout_s, lambda h: h["controller_alive"], "the simulated controller never came up")


#: A balance sample younger than this (s) says a physics controller's stream reaches the service now
#: (the controller publishes at 50 Hz).
BALANCE_FRESH_S = 0.5


def wait_balance_stream(srv: "Server", proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    """Wait until the server's balance watch hears the physics controller ``proc`` (``/healthz``'s
    ``balance_age_s`` fresh): its samples then reach the job's audit from the dispatch on."""
    wait_health(srv, proc, timeout_s, lambda h: h["balance_age_s"] is not None and h["balance_age_s"] < BALANCE_FRESH_S,
                "the controller's balance stream never reached the service")


def stop_process(proc: subprocess.Popen[bytes], timeout: float = 10.0) -> None:
    """SIGTERM, then SIGKILL if it has not exited within ``timeout`` s."""
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()


def service_env(bridge_port: int | None = None, **settings: Any) -> dict[str, str]:
    """Environment of a test server: test tokens and handlers, and a private zenoh endpoint for its bridge."""
    env = dict(os.environ)
    env["REGRASP_BRIDGE_CONNECT"] = json.dumps([f"tcp/127.0.0.1:{bridge_port or free_port()}"])
    env["REGRASP_BRIDGE_ROBOT_ID"] = BRIDGE_ROBOT_ID
    # The bridge's 250 ms controller watchdog is tested by the bridge's own tests; here, on a loaded
    # shared machine, a late heartbeat of the simulated controller must not abort the service's test.
    env["REGRASP_BRIDGE_WATCHDOG_TIMEOUT_S"] = str(BRIDGE_WATCHDOG_S)
    env["REGRASP_BRIDGE_LEASE_S"] = str(BRIDGE_LEASE_S)
    env["REGRASP_BRIDGE_SIGNING_KEY"] = bridge_keys()["private"]
    env["PYTHONPATH"] = os.pathsep.join([str(HERE), str(ROOT), env.get("PYTHONPATH", "")])
    env["REGRASP_TOKENS"] = json.dumps(TOKENS)
    env["REGRASP_HANDLERS"] = json.dumps(HANDLERS)
    env["REGRASP_CHECK_SCENARIO_NAMES"] = "false"
    env["REGRASP_PRELOAD_ROBOT"] = "false"
    for key, value in settings.items():
        env[f"REGRASP_{key.upper()}"] = value if isinstance(value, str) else json.dumps(value)
    return env


class Server:
    """A `regrasp serve` subprocess; ``kill()`` is a real SIGKILL of the server process only."""

    def __init__(self, data_dir: Path, workers: int = 2, port: int | None = None, extra_args: list[str] | None = None,
                 bridge_port: int | None = None, startup_timeout_s: float = STARTUP_TIMEOUT_S,
                 tls_ca: Path | None = None, **settings: Any) -> None:
        self.data_dir = data_dir
        self.port = port or free_port()
        #: With ``tls_ca`` (the CA file that signed the server's certificate) the server is reached over HTTPS.
        self.verify: Any = str(tls_ca) if tls_ca is not None else True
        self.url = f"{'https' if tls_ca is not None else 'http'}://127.0.0.1:{self.port}"
        self.args = [sys.executable, "-m", "service.cli.main", "serve", "--port", str(self.port),
                     "--data-dir", str(data_dir), "--workers", str(workers), "--log-level", "warning",
                     *(extra_args or [])]
        self.env = service_env(bridge_port, **settings)
        self.log_path = data_dir / f"server-{self.port}.log"
        self.proc: subprocess.Popen[bytes] | None = None
        self.startup_timeout_s = startup_timeout_s

    def start(self) -> "Server":
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self._log = open(self.log_path, "ab")
        self.proc = subprocess.Popen(self.args, cwd=ROOT, env=self.env, stdout=self._log, stderr=subprocess.STDOUT,
                                     start_new_session=True)
        deadline = time.monotonic() + self.startup_timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}: {self.log_path.read_text()[-3000:]}")
            try:
                if httpx.get(self.url + "/healthz", timeout=1.0, verify=self.verify).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        raise RuntimeError(f"server did not come up: {self.log_path.read_text()[-3000:]}")

    def wait_workers_ready(self, client: "httpx.Client", timeout: float = 60.0) -> None:
        """Workers load before they claim; a quick job finishing proves they are up."""
        job = client.post("/v1/jobs", json={"kind": "survey", "request": {"scenario": "quick"}}).json()
        wait_state(client, job["id"], {"succeeded"}, timeout)

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
            self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        try:  # anything left in the server's own session (its workers) goes too
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        self._log.close()

    def client(self, user: str) -> httpx.Client:
        return httpx.Client(base_url=self.url, headers={"Authorization": f"Bearer {TOKEN[user]}"}, timeout=30.0,
                            verify=self.verify)


def wait_state(client: httpx.Client, job_id: str, states: set[str], timeout: float = 30.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    job: dict[str, Any] = {}
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}", params={"include_result": "false"}).json()
        if job["state"] in states:
            return client.get(f"/v1/jobs/{job_id}").json()
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} did not reach {states} in {timeout} s: {job.get('state')} {job.get('message')}")


def schema_drift(engine: Any) -> list[Any]:
    """What Alembic's autogenerate finds between a migrated store and service.store.tables (empty: they agree).

    Columns, types, indexes and constraints: an index declared in one and not the other shows up here.
    """
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    from service.store.tables import metadata

    with engine.connect() as conn:
        return list(compare_metadata(MigrationContext.configure(conn, opts={"compare_type": True}), metadata))


def submit_approved_plan(srv: Server, request: dict[str, Any], timeout: float = 60.0) -> str:
    """Submit a plan job as alice, wait for it to be planned and approve its plan as bob; the job's id."""
    with srv.client("alice") as alice, srv.client("bob") as bob:
        r = alice.post("/v1/jobs", json={"kind": "plan", "request": request})
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        planned = wait_state(alice, job_id, {"planned", "failed"}, timeout)
        assert planned["state"] == "planned", planned["error"]
        r = bob.post(f"/v1/jobs/{job_id}/approve", json={"plan_sha256": planned["plan_sha256"]})
        assert r.status_code == 200, r.text
        return job_id



def closed_audit_events(srv: "Server", job_id: str, want: str | set[str] = "finished",
                        timeout_s: float = 20.0) -> list[tuple[str, dict[str, Any]]]:
    """(kind, payload) of the /audit/events records of every closed audit file of the job, in file order, once
    they hold a record of a kind in ``want`` (bounded wait: the audit process writes them after the events)."""
    from mcap.reader import make_reader

    wanted = {want} if isinstance(want, str) else set(want)
    deadline = time.monotonic() + timeout_s
    audit_dir = srv.data_dir / "audit"
    while True:
        files = sorted(audit_dir.glob(f"{job_id}*.mcap"), key=lambda p: (len(p.name), p.name))
        out: list[tuple[str, dict[str, Any]]] = []
        if files and all(p.read_bytes().endswith(MCAP_MAGIC) for p in files):
            for path in files:
                with open(path, "rb") as f:
                    for _, channel, msg in make_reader(f).iter_messages(log_time_order=False):
                        if channel.topic == "/audit/events":
                            body = json.loads(msg.data)
                            out.append((body["kind"], body["payload"]))
            if any(k in wanted for k, _ in out):
                return out
        assert time.monotonic() < deadline, f"no closed audit file of {job_id} with {sorted(wanted)}: {[p.name for p in files]}"
        time.sleep(0.2)

def job_events(client: httpx.Client, job_id: str) -> list[dict[str, Any]]:
    """The job's stored event history (the SSE stream without following)."""
    text = client.get(f"/v1/jobs/{job_id}/events", params={"follow": "false"}).text
    return [json.loads(line[len("data: "):]) for line in text.splitlines() if line.startswith("data: ")]


def cancel_latency_s(client: httpx.Client, job_id: str) -> float:
    """Server time from the stored cancel request of a planning job to its stored ``canceled`` state, s.

    Both timestamps are the server's, so the figure is the cancel's own latency, not the client's polling.
    """
    from datetime import datetime

    events = job_events(client, job_id)
    asked = next(e for e in events if e["kind"] == "note" and "cancel requested" in (e["message"] or ""))
    ended = next(e for e in events if e["kind"] == "state" and e["state"] == "canceled")
    return (datetime.fromisoformat(ended["at"]) - datetime.fromisoformat(asked["at"])).total_seconds()


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    # One user (alice) submits the load test's 200 jobs: the per-user queue limit is the hardening tests' to check.
    srv = Server(tmp_path_factory.mktemp("svc"), workers=2, approval_ttl_s="3", timeout_margin_s="0.5",
                 max_body_bytes="200000", user_queue_limit="1000").start()
    try:
        with srv.client("admin") as c:
            srv.wait_workers_ready(c)
        yield srv
    finally:
        srv.stop()


@pytest.fixture
def alice(server: Server) -> Iterator[httpx.Client]:
    with server.client("alice") as c:
        yield c


@pytest.fixture
def bob(server: Server) -> Iterator[httpx.Client]:
    with server.client("bob") as c:
        yield c
