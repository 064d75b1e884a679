"""The fault matrix against the real simulated controller process on loopback.

Each case ends in the right terminal status with its reason; after a veto a spy
peer on ``cmd/trajectory`` (connected to the dispatcher, which the test checks)
proves that nothing was sent.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest
import zenoh

from robot_bridge.dispatcher import (
    ControllerUnavailableError,
    Dispatcher,
    DispatchSettings,
)

from .conftest import approval_for
from .plans import build_plan, edited, true_min_margin

#: Rates, deadlines and watchdogs in wall-clock time: a failure while the VM's host paused the guest
#: for 0.2 s or more (the production watchdog is 0.25 s) measured the host, and the test runs again.
#: Every case runs against both plants: the physics twin obeys every rule the replay does.
pytestmark = [pytest.mark.host_pauses(limit_s=0.2), pytest.mark.usefixtures("plant")]


@pytest.fixture(scope="module", params=["kinematic", "physics"])
def plant(request) -> str:
    """The controller's plant (physics: the MuJoCo twin at speed 1)."""
    return request.param


#: How close the measured posture is to the commanded one: exact when replayed, within the servos' tracking (rad)
#: when physical; and how still a held posture is (rad over 0.1 s).
TRACKING_RAD = {"kinematic": 1e-12, "physics": 0.01}
HOLD_RAD = {"kinematic": 0.0, "physics": 0.002}


def assert_holding(disp, plant: str) -> None:
    """The robot holds its posture: the measured joints move no more than the plant's stillness over 0.1 s."""
    q1 = np.array(disp.measured_state().q)
    time.sleep(0.1)
    assert np.max(np.abs(q1 - np.array(disp.measured_state().q))) <= HOLD_RAD[plant]

#: Behavioural deadline of the contract (controller lost -> job aborted and stop sent), and the
#: small scheduling margin the tests allow on a loaded 2-core machine. Time during which the VM's
#: host ran no process of the guest (``host_stalls``) is allowed on top, and printed.
LOSS_DEADLINE_S = 0.3
MARGIN_S = 0.15
#: QoS of cmd/trajectory and cmd/stop: real-time priority, express, drop on congestion (never block).
CONTROL_QOS = (zenoh.Priority.REAL_TIME, True, zenoh.CongestionControl.DROP)


class Recorder:
    def __init__(self):
        self.events: list[tuple[float, str, dict]] = []
        self.lock = threading.Lock()

    def __call__(self, kind: str, data: dict) -> None:
        with self.lock:
            self.events.append((time.monotonic(), kind, data))

    def kinds(self) -> list[str]:
        return [k for _, k, _ in self.events]

    def first(self, kind: str):
        return next((e for e in self.events if e[1] == kind), None)

    def controller(self) -> list[dict]:
        """What the dispatcher recorded of the controller's statuses, in order."""
        return [d for _, k, d in self.events if k == "controller"]

    def refused_commands(self) -> list[dict]:
        """The controller's refusals of what the dispatcher sent, but for its heartbeats: a heartbeat that
        crosses the job's end on the wire is refused as of an ended job, whatever the test is about."""
        return [d for d in self.controller() if d["status"] == "refused" and d.get("kind") != "heartbeat"]


def run(disp, plan, job_id="job-1", approved_plan=None, expires_in=300.0, on_event=None, stop_event=None, threshold_m=None):
    sha, exp = approval_for(approved_plan if approved_plan is not None else plan, expires_in)
    rec = on_event or Recorder()
    res = disp.execute(plan, job_id=job_id, approved_sha256=sha, approval_expires_at=exp, on_event=rec,
                       stop_event=stop_event, threshold_m=threshold_m)
    return res, rec


def spy_saw_stop(spy, job_id: str, timeout_s: float = 1.0) -> bool:
    """Whether the spy received a stop for ``job_id`` (bounded wait: stops are re-sent, delivery is not instant)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if any(s["job_id"] == job_id for s in spy.stops):
            return True
        time.sleep(0.01)
    return False


def assert_nothing_sent(disp, spy, rec):
    assert disp.zid() in spy.peers()
    time.sleep(0.1)  # anything in flight would have arrived
    assert spy.trajectory == []
    assert "segment" not in rec.kinds() and "dispatching" not in rec.kinds()


# --------------------------------------------------------------------------- success


def test_valid_plan_is_executed(bridge, arm_plan, plant):
    ctl, disp, spy = bridge(speed=4.0)
    res, rec = run(disp, arm_plan)
    assert res.status == "succeeded", res.reason
    assert res.last_index == len(arm_plan["trajectory"]) - 1
    kinds = rec.kinds()
    assert kinds[0] == "gate" and kinds[1] == "dispatching" and "executing" in kinds and kinds[-1] == "finished"
    assert "robot_state" in kinds
    time.sleep(0.05)
    # A segment whose acknowledgement is late is sent again (a stalled host delays acks by 100s of ms):
    # every copy must be the same segment, signed afresh with an expiry no earlier than the last copy's, and the
    # distinct ones must cover the plan once, in order.
    by_seq: dict[int, list[dict]] = {}
    for s in spy.trajectory:
        by_seq.setdefault(s["seq"], []).append(s)

    def content(seg: dict) -> dict:
        return {k: v for k, v in seg.items() if k not in ("expires_at", "sig")}

    assert all(all(content(c) == content(copies[0]) for c in copies) for copies in by_seq.values())
    assert all(all(b["expires_at"] >= a["expires_at"] for a, b in zip(copies, copies[1:])) for copies in by_seq.values())
    segs = [by_seq[k][0] for k in sorted(by_seq)]
    assert [s["segment_index"] for s in segs] == list(range(segs[0]["segment_count"]))
    assert all(s["job_id"] == "job-1" and s["plan_sha256"] == res.verdict.plan_sha256 for s in segs)
    assert all((len(s["points"]) - 1) * s["dt_s"] <= 1.0 + 1e-9 for s in segs)
    # every segment crossed the wire with the control path's QoS
    assert spy.trajectory_qos and all(q == CONTROL_QOS for q in spy.trajectory_qos)
    assert np.allclose(np.vstack([s["points"] for s in segs]), [p["q"] for p in arm_plan["trajectory"]], atol=0)
    # the robot ends at the plan's last posture: exactly when replayed, within its servos' tracking when physical
    js = disp.measured_state()
    assert np.allclose(js.q, arm_plan["trajectory"][-1]["q"], atol=TRACKING_RAD[plant])
    if plant == "physics":
        assert not np.allclose(js.q, arm_plan["trajectory"][-1]["q"], atol=1e-9)  # measured, not the command


def _first_sends(rec) -> list[tuple[float, int]]:
    """Each segment's first send, in the dispatcher's own order of events: when, and how many segments were
    sent and not yet acknowledged just before it."""
    outstanding: set[int] = set()
    sends = []
    for _, kind, data in rec.events:
        if kind == "segment" and "sent_at" in data:
            sends.append((data["sent_at"], len(outstanding)))
            outstanding.add(data["seq"])
        elif kind == "segment" and data.get("acknowledged"):
            outstanding.discard(data["seq"])
    return sends


def _most_unacknowledged(rec) -> int:
    """The most segments ever sent and not yet acknowledged."""
    return max(before + 1 for _, before in _first_sends(rec))


@pytest.mark.parametrize("window", [1, None])
def test_unacknowledged_segments_never_exceed_the_window(bridge, long_plan, window):
    """The lookahead fills one acknowledgement at a time (no burst queued in the controller's receive path): at most
    ``max_in_flight_segments`` are ever outstanding, and that many are (13 segments, lookahead 8). The late-ack escape
    is set out of reach here (1 s) so that a slow acknowledgement on a loaded machine cannot open the window."""
    over = {"in_flight_wait_s": 1.0} | ({} if window is None else {"max_in_flight_segments": window})
    dispatch = DispatchSettings(**over)
    # Real time: with one segment in flight the controller waits a round trip for each, and a loaded machine's
    # round trip can outlast a segment played faster (62 ms at 4x).
    ctl, disp, spy = bridge(speed=1.0, dispatch=dispatch)
    res, rec = run(disp, long_plan)
    assert res.status == "succeeded", res.reason
    sent = [d for _, k, d in rec.events if k == "segment" and "sent_at" in d]
    assert [d["segment_index"] for d in sent] == list(range(sent[0]["segment_count"]))
    assert _most_unacknowledged(rec) == dispatch.max_in_flight_segments == (window or DispatchSettings().max_in_flight_segments)


def _sends_beyond_the_window(rec, window: int) -> list[float]:
    """When each segment went out for the first time while ``window`` or more were unacknowledged."""
    return [at for at, before in _first_sends(rec) if before >= window]


def test_late_acknowledgements_do_not_hold_the_lookahead_back(bridge, long_plan):
    """A controller that answers each command 60 ms late: once the oldest unacknowledged segment has waited
    ``in_flight_wait_s`` (10 ms), more of the lookahead goes out without waiting, as a controller playing fast
    needs it, but paced, one segment per ``in_flight_wait_s``: the whole lookahead in one burst overflowed
    zenoh's transmit queue at 10x (80 segments), and drop-on-congestion lost segments the robot then starved of."""
    dispatch = DispatchSettings()
    ctl, disp, spy = bridge("--delay-ms", "60", speed=4.0, dispatch=dispatch)
    res, rec = run(disp, long_plan)
    assert res.status == "succeeded", res.reason
    assert _most_unacknowledged(rec) > dispatch.max_in_flight_segments
    beyond = _sends_beyond_the_window(rec, dispatch.max_in_flight_segments)
    assert len(beyond) >= 3
    assert min(np.diff(beyond)) >= dispatch.in_flight_wait_s


def test_duplicated_segments_are_ignored_and_the_job_succeeds(bridge, long_plan):
    class Duplicating(Dispatcher):
        def _publish_segment(self, seg):
            super()._publish_segment(seg)
            super()._publish_segment(seg)

    ctl, disp, spy = bridge(speed=3.0, dispatcher_cls=Duplicating)
    res, rec = run(disp, long_plan)
    assert res.status == "succeeded", res.reason
    duplicates = [d for d in rec.controller() if d["status"] == "duplicate"]
    assert duplicates and "already held" in duplicates[0]["reason"]


def test_reordered_segments_are_refused_and_recovered(bridge, long_plan, plant):
    class Reordering(Dispatcher):
        """A faulty link: segment 2 overtakes segment 1 (once)."""

        held = None
        done = False

        def _publish_segment(self, seg):
            if seg.segment_index == 1 and not self.done:
                self.held, self.done = seg, True
                return
            super()._publish_segment(seg)
            if self.held is not None and seg.segment_index == 2:
                super()._publish_segment(self.held)
                self.held = None

    ctl, disp, spy = bridge(speed=2.0, dispatcher_cls=Reordering)
    res, rec = run(disp, long_plan)
    # the controller never plays out of order: it refuses segment 2, takes 1, then 2 again
    refused = rec.refused_commands()
    assert refused and "out of sequence" in refused[0]["reason"] and refused[0]["fatal"] is False
    assert res.status == "succeeded", res.reason
    js = disp.measured_state()
    assert np.allclose(js.q, long_plan["trajectory"][-1]["q"], atol=TRACKING_RAD[plant])


def test_lost_segments_are_sent_again(bridge, long_plan):
    ctl, disp, spy = bridge("--drop-rate", "0.25", "--seed", "3", speed=2.0)
    res, rec = run(disp, long_plan)
    assert res.status == "succeeded", res.reason
    assert any(k == "segment" and "resent" in d for _, k, d in rec.events)


def test_a_gap_is_filled_as_soon_as_the_controller_refuses_what_follows_it(bridge, long_plan, plant):
    """Segment 1 is lost once, with the re-send timer (2 s) out of reach: the controller, playing 4x
    (62 ms per segment), would starve long before it. Its refusal of segment 2 for the gap names what is
    missing, and segment 1 goes again at once, with segment 2 behind it."""

    class LosesSegmentOneOnce(Dispatcher):
        lost = False

        def _publish_segment(self, seg):
            if seg.segment_index == 1 and not self.lost:
                self.lost = True
                return
            super()._publish_segment(seg)

    # the physics twin plays at 1x (3.1 s of motion): its re-send timer is put as far out of reach
    dispatch = DispatchSettings(resend_after_s=2.0 if plant == "kinematic" else 8.0)
    ctl, disp, spy = bridge(speed=4.0, dispatcher_cls=LosesSegmentOneOnce, dispatch=dispatch)
    res, rec = run(disp, long_plan)
    assert res.status == "succeeded", res.reason
    assert res.duration_s < dispatch.resend_after_s
    resent = [d for _, k, d in rec.events if k == "segment" and "resent" in d]
    assert resent and resent[0]["cause"] == "gap" and resent[0]["behind_gap"] is False
    seq_of = {d["segment_index"]: d["seq"] for _, k, d in rec.events if k == "segment" and "sent_at" in d}
    assert resent[0]["seq"] == seq_of[1]


def test_segments_refused_behind_a_gap_keep_their_resend_budget(bridge, long_plan):
    """A link that delivers segment i only on its (i+1)-th send: each re-send round fills one gap and
    the controller refuses every segment behind it. Segment 6 is refused five times before its turn;
    had those refusals spent its budget of 5 re-sends, it would never come and the robot would starve."""

    class OneGapPerRound(Dispatcher):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.publishes: dict[int, int] = {}

        def _publish_segment(self, seg):
            n = self.publishes[seg.segment_index] = self.publishes.get(seg.segment_index, 0) + 1
            if seg.segment_index > 8 or n > seg.segment_index:
                super()._publish_segment(seg)

    dispatch = DispatchSettings(max_resends=5)
    ctl, disp, spy = bridge(speed=1.0, dispatcher_cls=OneGapPerRound, dispatch=dispatch)
    res, rec = run(disp, long_plan)
    assert res.status == "succeeded", res.reason
    assert disp.publishes[8] == 9  # sent once, then eight times more: more than its budget, behind gaps
    refused = rec.refused_commands()
    assert refused and all(d["fatal"] is False for d in refused)
    heartbeats = [d for d in rec.controller() if d.get("kind") == "heartbeat"]
    assert all("which this controller ended (succeeded)" in d["reason"] for d in heartbeats), heartbeats
    head_resends = [d["resent"] for _, k, d in rec.events if k == "segment" and "resent" in d and not d["behind_gap"]]
    assert max(head_resends) <= dispatch.max_resends


# --------------------------------------------------------------------------- vetoes: nothing is sent


def test_nan_waypoint_is_vetoed_and_nothing_sent(shared_bridge, arm_plan):
    ctl, disp, spy = shared_bridge
    bad = edited(arm_plan, lambda p: p["trajectory"][120]["q"].__setitem__(7, float("nan")))
    res, rec = run(disp, bad, approved_plan=arm_plan)
    assert res.status == "rejected" and res.verdict.check == "finite"
    assert res.verdict.point_index == 120 and "nan" in res.reason
    assert_nothing_sent(disp, spy, rec)


def test_plan_edited_after_approval_is_vetoed(shared_bridge, arm_plan):
    ctl, disp, spy = shared_bridge
    changed = edited(arm_plan, lambda p: p.__setitem__("threshold_m", 0.04))
    res, rec = run(disp, changed, approved_plan=arm_plan)
    assert res.status == "rejected" and res.verdict.check == "plan_hash" and "changed after approval" in res.reason
    assert_nothing_sent(disp, spy, rec)


def test_plan_below_the_policy_floor_is_vetoed_at_dispatch(shared_bridge, arm_plan):
    """Approved as it is, a plan made at 0 mm is not for this site: the gate's policy floor (built-in 30 mm)
    vetoes it before anything is sent, and the verdict names the policy by its hash."""
    from schemas.policy import default_policy

    ctl, disp, spy = shared_bridge
    low = edited(arm_plan, lambda p: p.__setitem__("threshold_m", 0.0))
    res, rec = run(disp, low)
    assert res.status == "rejected" and res.verdict.check == "policy" and "30.0 mm floor" in res.reason, res.reason
    assert res.verdict.policy_sha256 == default_policy().sha256()
    assert_nothing_sent(disp, spy, rec)


def test_expired_approval_is_vetoed(shared_bridge, arm_plan):
    ctl, disp, spy = shared_bridge
    res, rec = run(disp, arm_plan, expires_in=-1.0)
    assert res.status == "rejected" and res.verdict.check == "approval" and "expired" in res.reason
    assert_nothing_sent(disp, spy, rec)


def test_start_state_mismatch_is_vetoed(shared_bridge):
    ctl, disp, spy = shared_bridge
    # a valid motion, but it starts 0.05 rad away from where the robot stands
    plan = build_plan({"RSP": -0.3}, duration_s=1.0)
    j = plan["robot"]["joint_names"].index("RSP")
    shifted = edited(plan, lambda p: [pt["q"].__setitem__(j, pt["q"][j] - 0.05) for pt in p["trajectory"]])
    res, rec = run(disp, shifted)
    assert res.status == "rejected" and res.verdict.check == "start_state" and "RSP" in res.reason
    assert res.verdict.sample_index == 0
    assert_nothing_sent(disp, spy, rec)


def test_unstable_waypoints_injected_into_a_valid_plan_are_vetoed(shared_bridge):
    ctl, disp, spy = shared_bridge
    plan = build_plan({"RSP": -0.3}, duration_s=2.4, threshold_m=0.06)
    assert true_min_margin(plan) > 0.06
    # Inject a forward waist bend (within the joint limits and rates) and keep the plan's
    # own com/margin_m/zmp fields: the gate must not believe them.
    wp = plan["robot"]["joint_names"].index("WP")
    n = len(plan["trajectory"])
    bump = 0.5 * (1 - np.cos(2 * np.pi * np.arange(n) / (n - 1)))  # rest to rest, peak mid-plan
    lean = edited(plan, lambda p: [pt["q"].__setitem__(wp, pt["q"][wp] + 0.5 * b) for pt, b in zip(p["trajectory"], bump)])
    assert true_min_margin(lean) < 0.06 - 1e-4
    assert all(pt["margin_m"] > 0.06 for pt in lean["trajectory"])  # the plan's numbers still say "fine"
    res, rec = run(disp, lean)
    assert res.status == "rejected" and res.verdict.check == "com_margin"
    assert 0 < res.verdict.point_index < n - 1
    assert_nothing_sent(disp, spy, rec)


def test_no_controller_means_no_dispatch(bridge, arm_plan):
    ctl, disp, spy = bridge()
    ctl.kill()
    deadline = time.monotonic() + 2.0
    while disp.controller_alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not disp.controller_alive()
    sha, exp = approval_for(arm_plan)
    rec = Recorder()
    with pytest.raises(ControllerUnavailableError, match="controller"):
        disp.execute(arm_plan, job_id="j", approved_sha256=sha, approval_expires_at=exp, on_event=rec)
    assert rec.events == []
    assert_nothing_sent(disp, spy, rec)


def _freeze_until_state_is_stale(ctl, disp) -> None:
    """SIGSTOP the controller (as a pause of the machine would hold it) until the dispatcher's joint state is stale."""
    os.kill(ctl.proc.pid, signal.SIGSTOP)
    deadline = time.monotonic() + 3.0
    while disp.measured_state() is not None and time.monotonic() < deadline:
        time.sleep(0.005)
    assert disp.measured_state() is None and disp.controller_problem() is None  # token and heartbeat still fine


def test_dispatch_waits_for_a_fresh_state_after_a_pause(bridge, arm_plan):
    """A dispatch that starts while the controller's joint state is stale but its token is present waits (up to
    ``state_wait_s``) for a fresh state instead of refusing: here the controller resumes 0.3 s later."""
    ctl, disp, spy = bridge(speed=4.0, dispatch=DispatchSettings(state_max_age_s=0.2))
    _freeze_until_state_is_stale(ctl, disp)
    resume = threading.Timer(0.3, os.kill, (ctl.proc.pid, signal.SIGCONT))
    resume.start()
    try:
        res, rec = run(disp, arm_plan)
    finally:
        resume.join()
    assert res.status == "succeeded", res.reason
    assert rec.kinds()[0] == "gate"


def test_a_state_still_stale_after_the_wait_refuses_the_dispatch(bridge, arm_plan):
    ctl, disp, spy = bridge(speed=4.0, dispatch=DispatchSettings(state_max_age_s=0.2, state_wait_s=0.3))
    _freeze_until_state_is_stale(ctl, disp)
    rec = Recorder()
    try:
        started = time.monotonic()
        with pytest.raises(ControllerUnavailableError, match="joint state is unknown"):
            run(disp, arm_plan, on_event=rec)
        waited = time.monotonic() - started
    finally:
        os.kill(ctl.proc.pid, signal.SIGCONT)
    assert waited >= 0.3
    assert_nothing_sent(disp, spy, rec)


# --------------------------------------------------------------------------- faults during execution


def _when_executing(rec: Recorder, min_index: int, action) -> Recorder:
    """An event callback that runs ``action`` once, when execution passes ``min_index``."""
    fired = threading.Event()

    def on_event(kind, data):
        rec(kind, data)
        if kind == "executing" and (data.get("index") or 0) >= min_index and not fired.is_set():
            fired.set()
            rec("test_action", {"at": time.monotonic()})
            threading.Thread(target=action, daemon=True).start()

    return on_event


def _loss_times(rec: Recorder) -> tuple[float, float]:
    """When the dispatcher sent its stop and when it ended the job (monotonic seconds)."""
    stop_at = rec.first("stop_sent")[0]
    finished = rec.first("finished")
    assert finished is not None and finished[2]["status"] == "aborted"
    return stop_at, finished[0]


def assert_loss_handled_in_time(host_stalls, lost_at: float, rec: Recorder, what: str) -> None:
    """The stop went out and the job ended within the deadline of ``lost_at``, not counting time the host
    ran no process of the guest (a VM pause is not the bridge's latency; the probe does not see this process's
    own interpreter, so a slow dispatcher is never excused)."""
    stop_at, finished_at = _loss_times(rec)
    stolen_stop = host_stalls.stolen_between(lost_at, stop_at)
    stolen_end = host_stalls.stolen_between(lost_at, finished_at)
    print(f"{what} -> stop sent {(stop_at - lost_at) * 1000:.1f} ms, job aborted {(finished_at - lost_at) * 1000:.1f} ms "
          f"(host stalled the guest {stolen_stop * 1000:.0f} / {stolen_end * 1000:.0f} ms of it)")
    assert 0 < stop_at - lost_at - stolen_stop <= LOSS_DEADLINE_S + MARGIN_S
    assert 0 < finished_at - lost_at - stolen_end <= LOSS_DEADLINE_S + MARGIN_S


def test_controller_killed_mid_execution(bridge, long_plan, host_stalls):
    from robot_bridge.settings import BridgeSettings

    # the production watchdog (0.25 s): the 300 ms deadline is what is tested
    ctl, disp, spy = bridge(speed=2.0, watchdog_timeout_s=BridgeSettings().watchdog_timeout_s)
    rec = Recorder()
    killed = {}

    def kill():
        killed["at"] = time.monotonic()
        ctl.proc.kill()

    res, _ = run(disp, long_plan, on_event=_when_executing(rec, 150, kill))
    assert "at" in killed, f"the job ended before the kill: {res.reason}"
    assert res.status == "aborted" and "controller lost" in res.reason
    assert 150 <= res.last_index < len(long_plan["trajectory"]) - 1
    assert_loss_handled_in_time(host_stalls, killed["at"], rec, "killed")
    assert rec.kinds()[-1] == "finished"


def test_frozen_controller_process_aborts_within_the_watchdog(bridge, long_plan, host_stalls):
    """A hung controller (SIGSTOP): its socket stays open and its token lives until the lease ends
    (1 s), so only the heartbeat watchdog can meet the 300 ms deadline."""
    from robot_bridge.settings import BridgeSettings

    settings = BridgeSettings()
    ctl, disp, spy = bridge(speed=2.0, watchdog_timeout_s=settings.watchdog_timeout_s)
    rec = Recorder()
    frozen = {}

    def freeze():
        frozen["at"] = time.monotonic()
        os.kill(ctl.proc.pid, signal.SIGSTOP)

    try:
        res, _ = run(disp, long_plan, on_event=_when_executing(rec, 150, freeze))
    finally:
        ctl.kill()  # SIGKILL ends a stopped process too
    assert "at" in frozen, f"the job ended before the freeze: {res.reason}"
    assert res.status == "aborted" and "heartbeat" in res.reason
    assert_loss_handled_in_time(host_stalls, frozen["at"], rec, "frozen")


def test_heartbeat_stall_aborts_within_the_watchdog(bridge, long_plan, host_stalls, plant):
    from robot_bridge.settings import BridgeSettings

    # the production watchdog (0.25 s), so the 300 ms deadline is what is tested
    ctl, disp, spy = bridge("--freeze-heartbeat-after-s", "0.3", speed=2.0,
                            watchdog_timeout_s=BridgeSettings().watchdog_timeout_s)
    res, rec = run(disp, long_plan)
    assert res.status == "aborted" and "heartbeat" in res.reason
    assert ctl.proc.poll() is None  # the controller process is still alive, only its heartbeat froze
    silent_since = disp.last_heartbeat_at()  # the last heartbeat that arrived
    assert BridgeSettings().watchdog_timeout_s <= _loss_times(rec)[0] - silent_since  # not before the watchdog
    assert_loss_handled_in_time(host_stalls, silent_since, rec, "silent")
    # the controller is still reachable, so it received and honoured the stop: it no longer moves
    time.sleep(0.1)
    assert_holding(disp, plant)
    assert spy_saw_stop(spy, "job-1")


def test_crash_after_n_segments(bridge, long_plan):
    ctl, disp, spy = bridge("--crash-after", "2", speed=2.0, dispatch=DispatchSettings(lookahead_segments=1))
    res, rec = run(disp, long_plan)
    assert res.status == "aborted" and "controller lost" in res.reason
    assert ctl.proc.wait(timeout=5) == 3


def test_stop_during_execution(bridge, long_plan, plant):
    ctl, disp, spy = bridge(speed=1.0)
    rec = Recorder()
    res, _ = run(disp, long_plan, on_event=_when_executing(rec, 60, lambda: disp.stop("job-1")))
    assert res.status == "aborted" and res.reason == "stopped by operator"
    assert res.details["stop_acknowledged"] is True
    assert res.last_index < len(long_plan["trajectory"]) - 100
    assert spy_saw_stop(spy, "job-1")
    assert spy.stop_qos and all(q == CONTROL_QOS for q in spy.stop_qos)
    time.sleep(0.05)
    assert_holding(disp, plant)


def test_stop_event_from_the_service(bridge, long_plan):
    ctl, disp, spy = bridge(speed=1.0)
    stop = threading.Event()
    rec = Recorder()
    res, _ = run(disp, long_plan, on_event=_when_executing(rec, 40, stop.set), stop_event=stop)
    assert res.status == "aborted" and res.reason == "stopped by operator"


def test_all_commands_dropped_ends_without_progress(bridge, arm_plan):
    ctl, disp, spy = bridge("--drop-rate", "1.0", dispatch=DispatchSettings(progress_timeout_s=0.5))
    res, rec = run(disp, arm_plan)
    assert res.status == "aborted" and "no progress" in res.reason


def test_delayed_commands_still_execute(bridge, arm_plan):
    ctl, disp, spy = bridge("--delay-ms", "30", speed=4.0)
    res, rec = run(disp, arm_plan)
    assert res.status == "succeeded", res.reason
