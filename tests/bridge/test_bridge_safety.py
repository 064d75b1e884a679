"""Safety on the robot's side of the wire, against the real ``regrasp controller-sim`` process on loopback.

The controller must hold what the dispatcher promises even when it was frozen,
when the dispatcher died, or when a peer lies to it: a frozen and resumed
controller plays nothing more of the aborted job and reports ``stopped``; a
killed dispatcher's robot stops within the controller's own watchdog; a rogue
peer's commands (unsigned, wrongly signed, replayed, expired, another job's, out
of sequence) are refused with their reason and move nothing.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from robot_bridge.settings import BridgeSettings
from robot_bridge.signing import Signer, generate_keys
from robot_bridge.zenoh_session import encode

from .conftest import RELAXED_WATCHDOG_S, REPO, approval_for, start_controller
from .test_controller_sim import (
    Peer,
    _assert_still,
    _idle,
    _posture_after,
    cosine_move,
    new_job,
    segments,
)
from .test_fault_matrix import Recorder, _when_executing

#: Wall-clock deadlines: a failure while the VM's host paused the guest for 0.2 s or more measured the
#: host, and the test runs again.
pytestmark = pytest.mark.host_pauses(limit_s=0.2)

#: The production watchdog, on both sides.
WATCHDOG_S = BridgeSettings().watchdog_timeout_s
#: Scheduling margin on a loaded two-core machine (the host's own pauses are allowed on top).
MARGIN_S = 0.15
#: How long a frozen controller stays frozen: longer than the segments' expiry and the zenoh lease.
FROZEN_S = 1.5


#: A controller that was frozen past the zenoh lease reports again once its session is re-established: seconds on a
#: loaded two-core machine. What it plays meanwhile is what these tests check, not how soon it speaks.
REPORT_AFTER_RESUME_S = 10.0


def _stopped_after(peer: Peer, after: float, job_id: str, timeout_s: float = REPORT_AFTER_RESUME_S):
    return peer.reply(after, "stopped", job_id, timeout_s)


def _reported_stopped_after_resume(peer: Peer, resumed: float, job_id: str) -> tuple[float, str]:
    """(arrival, reason) of the controller's first report after ``resumed`` that it stopped ``job_id``: its
    state/exec status, or the same end repeated in its heartbeat while it holds (the repetition is how a listener
    whose session was re-established after the freeze learns an end it missed). On a timeout the message says what
    was heard since the resume, so a silent controller and a lost status can be told apart."""
    def find() -> tuple[float, str, str] | None:
        with peer._lock:
            found = [(at, st.reason, "state/exec") for at, st in peer.exec if at >= resumed
                     and st.status == "stopped" and st.job_id == job_id]
            found += [(at, hb.reason, "heartbeat") for at, hb in peer.beats if at >= resumed
                      and hb.status == "stopped" and hb.job_id == job_id]
        return min(found, default=None)
    deadline = time.monotonic() + REPORT_AFTER_RESUME_S
    while time.monotonic() < deadline:
        if (report := find()) is not None:
            print(f"'stopped' heard {report[0] - resumed:.2f} s after the resume, first on {report[2]}")
            return report[:2]
        time.sleep(0.01)
    with peer._lock:
        heard = {name: sum(1 for at, _ in got if at >= resumed)
                 for name, got in (("exec", peer.exec), ("heartbeats", peer.beats), ("joint states", peer.joints))}
        last_beat = peer.beats[-1][1] if peer.beats else None
    raise AssertionError(f"no 'stopped' report for {job_id} within {REPORT_AFTER_RESUME_S} s of the resume; heard "
                         f"since: {heard}; last heartbeat: {last_beat}")


# --------------------------------------------------------------------------- freeze and resume


@pytest.mark.parametrize("at_index", [0, 120, 420])
def test_a_frozen_controller_plays_nothing_more_of_the_aborted_job_when_it_resumes(
        spawn_controller, spy_factory, key_pair, long_plan, at_index):
    """SIGSTOP mid-execution (at the job's start, early, late), the dispatcher aborts it, SIGCONT 1.5 s later:
    every joint state the controller publishes after it resumes is the posture it was frozen in, it reports
    ``stopped`` for the job, and the dispatcher sends the stop again once it hears from it (recorded)."""
    from .conftest import connect_dispatcher

    ctl = spawn_controller(speed=2.0, watchdog_s=WATCHDOG_S)
    spy = spy_factory(ctl.robot_id)
    returned: list[tuple[str, dict]] = []
    disp = connect_dispatcher(ctl, spy, watchdog_timeout_s=WATCHDOG_S, signing_key=key_pair.private,
                              on_controller_return=lambda job, data: returned.append((job, data)))
    watcher = Peer(ctl)
    try:
        rec = Recorder()
        frozen = {}

        def freeze():
            frozen["at"] = time.monotonic()
            os.kill(ctl.proc.pid, signal.SIGSTOP)

        sha, exp = approval_for(long_plan)
        res = disp.execute(long_plan, job_id="frozen-job", approved_sha256=sha, approval_expires_at=exp,
                           on_event=_when_executing(rec, at_index, freeze))
        assert "at" in frozen, f"the job ended before the freeze: {res.reason}"
        assert res.status == "aborted" and "controller lost" in res.reason, res.reason
        aborted_at = rec.first("finished")[0]
        time.sleep(max(0.0, frozen["at"] + FROZEN_S - time.monotonic()))
        resumed = time.monotonic()
        os.kill(ctl.proc.pid, signal.SIGCONT)
        _, reason = _reported_stopped_after_resume(watcher, resumed, "frozen-job")
        assert "dead-man" in reason or "stop" in reason, reason
        # A second of the controller's own states after it resumed (its stamps are this host's monotonic clock).
        watcher.wait_for(lambda: any(js.stamp > resumed + 1.0 for _, js in watcher.joints_since(resumed)),
                         "a second of joint states after the resume")
        states = sorted((js for _, js in watcher.joints), key=lambda js: js.stamp)
        before = [js for js in states if js.stamp <= aborted_at]
        after = [js for js in states if js.stamp >= resumed]
        assert before and after
        # The freeze may land between a tick's step and its publication, so the posture it holds may be one
        # tick (2 plan samples at speed 2 and 200 Hz) past the last state published before it; after that, nothing.
        held = np.array(after[0].q)
        assert all(np.array_equal(js.q, held) for js in after), "the controller moved after the abort"
        q = np.array([p["q"] for p in long_plan["trajectory"]])
        one_tick = 4 * float(np.max(np.abs(np.diff(q, axis=0))))
        assert float(np.max(np.abs(held - np.array(before[-1].q)))) <= one_tick, "it played on while frozen"
        assert all(js.job_id is None for js in after)
        # The dispatcher heard from the controller again and sent the stop once more, saying so.
        watcher.wait_for(lambda: returned, "the stop re-sent when the controller came back")
        assert returned[0][0] == "frozen-job" and "re-sent" in returned[0][1]["reason"]
    finally:
        watcher.close()
        disp.close()
        try:
            os.kill(ctl.proc.pid, signal.SIGCONT)
        except ProcessLookupError:
            pass


# --------------------------------------------------------------------------- the dispatcher dies

_DISPATCHER_SCRIPT = """
import json, sys, threading
from datetime import datetime, timedelta, timezone
from robot_bridge.dispatcher import Dispatcher
from robot_bridge.settings import BridgeSettings
from schemas.plan import plan_sha256
args = json.loads(sys.argv[1])
plan = json.load(open(args["plan"]))
disp = Dispatcher(BridgeSettings(robot_id=args["robot_id"], connect=[args["endpoint"]], signing_key=args["key"],
                                 watchdog_timeout_s=5.0))
assert disp.wait_for_controller(20.0), disp.controller_problem()
said = threading.Event()
def on_event(kind, data):
    if kind == "executing" and (data.get("index") or 0) >= 100 and not said.is_set():
        said.set()
        print("EXECUTING", flush=True)
disp.execute(plan, job_id="orphan-job", approved_sha256=plan_sha256(plan),
             approval_expires_at=datetime.now(timezone.utc) + timedelta(minutes=5), on_event=on_event)
print("ENDED", flush=True)
"""


def test_a_killed_dispatcher_stops_the_robot_within_the_controller_watchdog(spawn_controller, key_pair, long_plan,
                                                                             tmp_path, host_stalls):
    ctl = spawn_controller(speed=1.0, watchdog_s=WATCHDOG_S)
    watcher = Peer(ctl)
    plan_file = tmp_path / "plan.json"
    plan_file.write_text(json.dumps(long_plan))
    args = {"plan": str(plan_file), "robot_id": ctl.robot_id, "endpoint": ctl.endpoint, "key": key_pair.private}
    proc = subprocess.Popen([sys.executable, "-c", _DISPATCHER_SCRIPT, json.dumps(args)], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert line.strip() == "EXECUTING", proc.stderr.read()
        killed = time.monotonic()
        proc.kill()
        at, st = _stopped_after(watcher, killed, "orphan-job")
        assert "dead-man" in st.reason, st.reason
        stolen = host_stalls.stolen_between(killed, at)
        print(f"dispatcher killed -> controller stopped {(at - killed) * 1000:.0f} ms later "
              f"(host stalled the guest {stolen * 1000:.0f} ms of it)")
        assert at - killed - stolen <= WATCHDOG_S + MARGIN_S
        # The stop is the controller's own: it holds its posture from then on (the first state published without
        # the job; the latest on the reply's arrival can be one published before the stop).
        _assert_still(watcher, _posture_after(watcher, at))
    finally:
        proc.kill()
        proc.wait(10)
        watcher.close()


def test_a_dispatcher_whose_heartbeat_stops_is_stopped_by_the_controller(bridge, long_plan):
    """The dispatcher stays up but its heartbeat stops (its thread stalled): the controller stops by itself and the
    execution ends aborted with the controller's word for it."""
    from robot_bridge.dispatcher import Dispatcher

    class SilentAfterStart(Dispatcher):
        def _begin_heartbeat(self, job_id):
            super()._begin_heartbeat(job_id)
            threading.Timer(0.5, self._end_heartbeat).start()

    ctl, disp, spy = bridge(speed=1.0, dispatcher_cls=SilentAfterStart, controller_watchdog_s=WATCHDOG_S)
    sha, exp = approval_for(long_plan)
    rec = Recorder()
    res = disp.execute(long_plan, job_id="silent-job", approved_sha256=sha, approval_expires_at=exp, on_event=rec)
    assert res.status == "aborted" and "controller stopped" in res.reason and "dead-man" in res.reason, res.reason
    assert res.last_index < len(long_plan["trajectory"]) - 1


# --------------------------------------------------------------------------- a rogue peer


@pytest.fixture(scope="module")
def guarded(initial_q_file, key_pair, tmp_path_factory):
    """A controller trusting the session's key; a peer holding that key and a rogue holding another one."""
    ctl = start_controller(initial_q_file, speed=2.0, trusted_key=key_pair.public, watchdog_s=RELAXED_WATCHDOG_S)
    rogue_key, _ = generate_keys(tmp_path_factory.mktemp("rogue"))
    peer = Peer(ctl, key_pair.private)
    rogue = Peer(ctl, str(rogue_key))
    yield ctl, peer, rogue
    rogue.close()
    peer.close()
    ctl.terminate()


def _move(peer: Peer, job_id: str | None = None, delta: float = -0.1, duration_s: float = 0.5):
    names, q0 = _idle(peer)
    Q = cosine_move(q0, names.index("RSP"), delta, duration_s, 0.01)
    return q0, Q, segments(job_id or new_job(), names, Q, 0.01, duration_s=0.25)


def _wire(signer: Signer | None, seg, expires_at: float | None = None, **changes) -> bytes:
    doc = seg.model_dump(mode="json", exclude={"sig"}) | {"expires_at": time.time() + 5.0 if expires_at is None else expires_at}
    doc.update(changes)
    return signer.encode(doc) if signer is not None else json.dumps(doc).encode()


def _refused(peer: Peer, sent: float, job_id: str, q0: np.ndarray, *words: str) -> None:
    """The controller refused the command with a reason naming ``words``, and did not move."""
    _, st = peer.reply(sent, "refused", job_id)
    for w in words:
        assert w in st.reason, st.reason
    assert st.seq is not None
    _assert_still(peer, q0, seconds=0.3)


def _send_raw(peer: Peer, payload: bytes) -> float:
    sent = time.monotonic()
    peer._traj.put(payload)
    return sent


@pytest.mark.parametrize("case", ["unsigned", "wrongly signed", "expired", "expires too late", "out of sequence",
                                  "tampered"])
def test_a_rogue_command_is_refused_and_moves_nothing(guarded, case):
    ctl, peer, rogue = guarded
    q0, Q, segs = _move(peer)
    seg = segs[0]
    payload = {
        "unsigned": lambda: _wire(None, seg),
        "wrongly signed": lambda: _wire(rogue.signer, seg),
        "expired": lambda: _wire(peer.signer, seg, expires_at=time.time() - 2.0),
        # signed with the real key, valid for an hour: a leaked command must not stay playable that long
        "expires too late": lambda: _wire(peer.signer, seg, expires_at=time.time() + 3600.0),
        "out of sequence": lambda: _wire(peer.signer, segs[1]),
        # signed, then one number changed on the way
        "tampered": lambda: _wire(peer.signer, seg).replace(b'"segment_count":2', b'"segment_count":3'),
    }[case]()
    words = {"unsigned": ["unsigned"], "wrongly signed": ["does not verify"], "expired": ["expired"],
             "expires too late": ["expires_at too far ahead", "10 s allowed"], "out of sequence": ["out of sequence"], "tampered": ["does not verify"]}[case]
    _refused(peer, _send_raw(rogue, payload), seg.job_id, q0, *words)


def test_a_replayed_segment_of_an_ended_job_is_refused(guarded):
    """A valid segment recorded off the wire and sent again after its job succeeded: the controller remembers the
    jobs it ended and refuses it (and once its receipt deadline has passed, it is refused as expired)."""
    ctl, peer, rogue = guarded
    q0, Q, segs = _move(peer, delta=-0.08)
    recorded = [_wire(peer.signer, s, expires_at=time.time() + 1.0) for s in segs]
    sent = _send_raw(peer, recorded[0])
    for payload in recorded[1:]:
        _send_raw(peer, payload)
    peer.reply(sent, "succeeded", segs[0].job_id, timeout_s=10.0)
    q_end = np.array(Q[-1])
    _refused(peer, _send_raw(rogue, recorded[0]), segs[0].job_id, q_end, "was ended by this controller (succeeded)")
    time.sleep(max(0.0, sent + 1.0 + BridgeSettings().clock_skew_s + 0.1 - time.monotonic()))
    _refused(peer, _send_raw(rogue, recorded[0]), segs[0].job_id, q_end, "expired")


def test_another_jobs_segment_is_refused_while_one_runs(guarded):
    ctl, peer, rogue = guarded
    q0, Q, segs = _move(peer, delta=-0.1, duration_s=1.0)
    sent = peer.send(segs[0])
    for s in segs[1:]:
        peer.send(s)
    peer.reply(sent, "accepted", segs[0].job_id)
    names = list(peer.latest().joint_names)
    other = segments(new_job(), names, np.repeat(Q[:1], 30, axis=0), 0.01)
    intruder = _send_raw(rogue, _wire(peer.signer, other[0]))  # validly signed, but not the running job
    _, st = peer.reply(intruder, "refused", other[0].job_id)
    assert f"another job is running: {segs[0].job_id}" in st.reason
    done, _ = peer.reply(sent, "succeeded", segs[0].job_id, timeout_s=10.0)
    # the first state after the job ended (the latest one on arrival of the reply can still be a sample of the job)
    assert np.array_equal(_posture_after(peer, done), Q[-1])  # the running job went on, and only it moved the robot


def test_an_unsigned_stop_is_obeyed_and_logged(guarded):
    ctl, peer, rogue = guarded
    q0, Q, segs = _move(peer, delta=-0.15, duration_s=1.5)
    sent = peer.send(segs[0])
    for s in segs[1:]:
        peer.send(s)
    peer.reply(sent, "executing", segs[0].job_id)
    stop_at = time.monotonic()
    rogue._stop.put(json.dumps({"job_id": None, "reason": "unsigned test stop"}).encode())
    stopped, st = peer.reply(stop_at, "stopped", segs[0].job_id)
    assert "unsigned" in st.reason
    # The posture it holds: the first state published without the job. The latest state on the reply's arrival can
    # be one published before the stop, and a tick under way when the stop came still plays its step.
    q_stop = _posture_after(peer, stopped)
    _assert_still(peer, q_stop)
    assert not np.array_equal(q_stop, Q[-1])


def test_without_a_trusted_key_the_controller_obeys_only_stop(initial_q_file, key_pair):
    ctl = start_controller(initial_q_file, speed=2.0, watchdog_s=RELAXED_WATCHDOG_S)  # no --trusted-key
    peer = Peer(ctl, key_pair.private)
    try:
        q0, Q, segs = _move(peer)
        _refused(peer, peer.send(segs[0]), segs[0].job_id, q0, "no trusted key")
        stop_at = peer.stop()
        _, st = peer.reply(stop_at, "stopped")
        assert "no trusted key" in st.reason
    finally:
        peer.close()
        ctl.terminate()


def test_unsigned_messages_from_a_rogue_do_not_end_a_running_execution(bridge, long_plan, key_pair):
    """Forged copies of the running job's segments are refused by the controller; the dispatcher records the
    refusals and its execution goes on to succeed."""
    from robot_bridge.dispatcher import Dispatcher

    class Forged(Dispatcher):
        def _publish_segment(self, seg):
            super()._publish_segment(seg)
            self._pub_traj.put(encode(seg))  # an unsigned copy, as a rogue peer would send it

    ctl, disp, spy = bridge(speed=2.0, dispatcher_cls=Forged)
    sha, exp = approval_for(long_plan)
    rec = Recorder()
    res = disp.execute(long_plan, job_id="forged-job", approved_sha256=sha, approval_expires_at=exp, on_event=rec)
    assert res.status == "succeeded", res.reason
    refused = rec.refused_commands()
    assert refused and all("unsigned" in d["reason"] for d in refused)
