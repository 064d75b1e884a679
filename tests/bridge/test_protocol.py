"""Wire messages, segmenting and the zenoh configuration."""

from __future__ import annotations

import json
import threading
import time

import pytest
from pydantic import ValidationError

from robot_bridge.dispatcher import split_segments
from robot_bridge.settings import BridgeSettings, Keys
from robot_bridge.zenoh_session import make_config, open_session
from schemas.bridge import TrajectorySegment

from .conftest import free_port
from .plans import build_plan

#: How long the listening peer is away: past zenoh's own 4 s longest wait between connect attempts.
PEER_AWAY_S = 4.5
#: How soon after the peer is back its samples must arrive: the settings' 1 s longest wait, and slack for a busy host
#: (zenoh's own doubling waits took 2-2.5 s after this absence).
REFOUND_WITHIN_S = 1.8


def _segment(**over):
    doc = dict(job_id="j", plan_sha256="a" * 64, seq=1, segment_index=0, segment_count=1, joint_names=["A", "B"],
               dt_s=0.005, t_from_start=0.0, points=[[0.0, 0.0], [0.001, 0.0]], holding=["none", "none"])
    doc.update(over)
    return TrajectorySegment(**doc)


def test_split_segments_cover_the_plan_in_order():
    plan = build_plan({"RSP": -0.2}, duration_s=2.3)
    segs = split_segments(plan, "job", "b" * 64, first_seq=10, segment_duration_s=1.0)
    assert [s.seq for s in segs] == list(range(10, 10 + len(segs)))
    assert [s.segment_index for s in segs] == list(range(len(segs)))
    points = [p for s in segs for p in s.points]
    assert points == [p["q"] for p in plan["trajectory"]]
    for s in segs:
        assert (len(s.points) - 1) * s.dt_s <= 1.0 + 1e-9
        assert s.t_from_start == pytest.approx(s.first_index * plan["dt_s"])
        assert s.joint_names == plan["robot"]["joint_names"]


def test_segment_validation():
    _segment()
    with pytest.raises(ValidationError, match="finite"):
        _segment(points=[[0.0, float("nan")], [0.0, 0.0]])
    with pytest.raises(ValidationError, match="at most 1.0 s"):
        _segment(points=[[0.0, 0.0]] * 202, holding=["none"] * 202)
    with pytest.raises(ValidationError, match="holding"):
        _segment(holding=["none"])
    with pytest.raises(ValidationError, match="segment_index"):
        _segment(segment_index=1, segment_count=1)
    with pytest.raises(ValidationError):
        _segment(extra_field=1)  # commands are strict


def test_bridge_settings_and_zenoh_config():
    s = BridgeSettings(robot_id="hrp5p", listen=["tcp/127.0.0.1:7500"], connect=[])
    cfg = make_config(s)
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7500"]
    assert json.loads(cfg.get_json("transport/link/tx/lease")) == 1000
    # shared memory off unless asked for: the robot's controller is on another host, so loopback takes its TCP path
    assert json.loads(cfg.get_json("transport/shared_memory/enabled")) is False
    assert json.loads(make_config(BridgeSettings(shared_memory=True)).get_json("transport/shared_memory/enabled")) is True
    with pytest.raises(ValidationError, match="locator"):
        BridgeSettings(connect=["127.0.0.1:7447"])
    with pytest.raises(ValidationError, match="heartbeat"):
        BridgeSettings(heartbeat_period_s=0.2, watchdog_timeout_s=0.3)
    with pytest.raises(ValidationError, match="connect_retry_max_s"):
        BridgeSettings(connect_retry_s=2.0, connect_retry_max_s=1.0)
    k = Keys("hrp5p")
    assert (k.trajectory, k.stop, k.joints, k.exec, k.heartbeat, k.alive) == (
        "regrasp/hrp5p/cmd/trajectory", "regrasp/hrp5p/cmd/stop", "regrasp/hrp5p/state/joints",
        "regrasp/hrp5p/state/exec", "regrasp/hrp5p/state/heartbeat", "regrasp/hrp5p/alive/controller")


def test_settings_from_environment(monkeypatch):
    monkeypatch.setenv("REGRASP_BRIDGE_CONNECT", '["tcp/10.0.0.2:7447"]')
    monkeypatch.setenv("REGRASP_BRIDGE_ROBOT_ID", "hrp5p-real")
    s = BridgeSettings()
    assert s.connect == ["tcp/10.0.0.2:7447"] and s.robot_id == "hrp5p-real"


def test_control_publishers_are_declared_with_the_control_qos():
    """cmd/trajectory and cmd/stop: real-time priority, drop on congestion (express is checked on the wire by the spy)."""
    import zenoh

    from robot_bridge.dispatcher import Dispatcher

    from .conftest import free_port

    settings = BridgeSettings(robot_id="qos", listen=[f"tcp/127.0.0.1:{free_port()}"], connect=[])
    with Dispatcher(settings) as disp:
        for pub, key in ((disp._pub_traj, disp.keys.trajectory), (disp._pub_stop, disp.keys.stop)):
            assert str(pub.key_expr) == key
            assert pub.priority == zenoh.Priority.REAL_TIME
            assert pub.congestion_control == zenoh.CongestionControl.DROP


def test_a_peer_that_went_away_is_connected_again_within_the_longest_retry_wait():
    """A controller restarted on its endpoint reaches every peer of the service again within about
    ``connect_retry_max_s``, the telemetry's as well as the commands' (zenoh's own waits double to 4 s)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    listener = open_session(BridgeSettings(listen=[endpoint], connect=[]))
    follower = open_session(BridgeSettings(connect=[endpoint]))
    heard = threading.Event()
    follower.declare_subscriber("regrasp/test/refound", lambda sample: heard.set())
    try:
        time.sleep(0.5)
        listener.close()
        time.sleep(PEER_AWAY_S)
        listener = open_session(BridgeSettings(listen=[endpoint], connect=[]))
        back = time.monotonic()
        publisher = listener.declare_publisher("regrasp/test/refound")
        while not heard.is_set() and time.monotonic() - back < 10.0:
            publisher.put(b"x")
            heard.wait(0.01)
        assert heard.is_set(), "the follower never connected again"
        assert time.monotonic() - back < REFOUND_WITHIN_S
    finally:
        listener.close()
        follower.close()
