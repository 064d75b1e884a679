"""The Foxglove side: /tf agrees with pinocchio, markers and playback are well formed."""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
from mcap.reader import make_reader

from planner.robot.model import frame_poses, load_robot
from service.audit import AuditWriter, shrink_polygon, verify
from service.audit.urdf_frames import parse_urdf

from .conftest import tiny_plan


def _compose(transforms: list[dict], frame: str) -> pin.SE3:
    by_child = {t["child_frame_id"]: t for t in transforms}
    pose = pin.SE3.Identity()
    while frame in by_child:
        t = by_child[frame]
        r = t["rotation"]
        q = pin.Quaternion(r["w"], r["x"], r["y"], r["z"])
        p = np.array([t["translation"][k] for k in "xyz"])
        pose = pin.SE3(q.matrix(), p) * pose
        frame = t["parent_frame_id"]
    assert frame == "world"
    return pose


def test_tf_places_links_where_pinocchio_does(tmp_path, hrp5p_urdf):
    robot = load_robot("hrp5p")
    rng = np.random.default_rng(7)
    q = rng.uniform(robot.lower, robot.upper)
    base = np.array([0.05, -0.02, 0.88, 0.0, 0.0, np.sin(0.2), np.cos(0.2)])
    path = tmp_path / "a.mcap"
    w = AuditWriter(path, "j", robot_name="hrp5p", urdf_text=hrp5p_urdf)
    w.joint_state(list(robot.joint_names), q, source="plan", base_pose=base)
    w.close()
    with open(path, "rb") as f:
        tf = [json.loads(m.data) for _s, _c, m in make_reader(f).iter_messages(topics=["/plan/tf"])][0]["transforms"]
    data = robot.create_data()
    # Links that carry a frame of the same name in pinocchio (URDF links become body frames).
    tree = parse_urdf(hrp5p_urdf)
    links = [j.child for j in tree.moving]
    expected = frame_poses(robot, data, base, q, links)
    for link, want in zip(links, expected):
        got = _compose(tf, link)
        assert np.allclose(got.translation, want.translation, atol=1e-9), link
        assert np.allclose(got.rotation, want.rotation, atol=1e-9), link


def test_plan_playback_is_downsampled_and_keeps_the_last_point(tmp_path):
    plan = tiny_plan(101)  # 0.5 s at 5 ms
    path = tmp_path / "a.mcap"
    w = AuditWriter(path, "j", robot_name=None, urdf_text=None)
    w.plan_playback(plan, start_ns=10**18)
    w.close()
    with open(path, "rb") as f:
        msgs = list(make_reader(f).iter_messages(topics=["/plan/joint_states", "/plan/markers/com", "/plan/markers/support"]))
    plan_states = [m for _s, c, m in msgs if c.topic == "/plan/joint_states"]
    assert len(plan_states) == 26  # 50 Hz over 0.5 s, both ends included
    last = json.loads(plan_states[-1].data)
    assert last["joints"][0]["position"] == plan["trajectory"][-1]["q"][0]
    assert plan_states[-1].log_time == 10**18 + 500_000_000
    support = [json.loads(m.data) for _s, c, m in msgs if c.topic == "/plan/markers/support"][0]
    lines = support["entities"][0]["lines"]
    assert len(lines) == 2 and lines[0]["type"] == 1  # polygon and shrunk polygon, closed loops
    inner = [(p["x"], p["y"]) for p in lines[1]["points"]]
    assert max(abs(x) for x, _ in inner) == np.float64(0.06) or np.isclose(max(abs(x) for x, _ in inner), 0.06)
    assert verify(path).exit_code == 0


def test_shrink_polygon_offsets_inward():
    square = [[1, 1], [-1, 1], [-1, -1], [1, -1]]
    inner = shrink_polygon(square, 0.25)
    assert np.allclose(sorted(map(tuple, np.abs(inner))), [(0.75, 0.75)] * 4)
    assert shrink_polygon(square, 2.0) == []


def test_record_of_a_plan_document_adds_the_model_and_its_playback(tmp_path):
    """The service only calls record(kind, payload): the Foxglove views follow from it."""
    robot = load_robot("hrp5p")
    plan = tiny_plan(21)
    plan["schema"] = "regrasp.plan/1"
    plan["robot"] = {"name": "hrp5p", "joint_names": list(robot.joint_names)}
    for point in plan["trajectory"]:
        point["q"] = robot.default_q().tolist()
    path = tmp_path / "a.mcap"
    w = AuditWriter(path, "job-7")
    w.record("plan", {"plan_sha256": "x", "document": plan})
    w.record("exec", {"data": {"joint_names": list(robot.joint_names), "q": robot.default_q().tolist()}})
    head = w.close()
    with open(path, "rb") as f:
        topics = [c.topic for _s, c, _m in make_reader(f).iter_messages()]
    assert topics.count("/robot_description") == 1
    assert topics.count("/plan/joint_states") == 6  # 0.1 s at 50 Hz, both ends included
    assert topics.count("/robot/joint_states") == 1
    assert verify(path, head).exit_code == 0


def test_executed_states_are_all_recorded_and_tf_is_rate_limited(tmp_path, hrp5p_urdf):
    path = tmp_path / "a.mcap"
    w = AuditWriter(path, "j", urdf_text=hrp5p_urdf)
    t0 = 10**18
    for i in range(50):  # 200 Hz for 0.25 s
        w.joint_state(["LCY"], [0.001 * i], source="executed", log_time_ns=t0 + i * 5_000_000)
    w.close()
    with open(path, "rb") as f:
        topics = [c.topic for _s, c, _m in make_reader(f).iter_messages()]
    assert topics.count("/robot/joint_states") == 50
    assert topics.count("/robot/tf") == 7  # 25 Hz over 0.25 s: t = 0, 40, ..., 240 ms


def test_executed_states_are_placed_at_the_plan_stance(tmp_path, hrp5p_urdf):
    """The bridge echoes joints only; the floating base stays at the plan's stance pose."""
    path = tmp_path / "a.mcap"
    w = AuditWriter(path, "j", urdf_text=hrp5p_urdf)
    w.plan_playback(tiny_plan())
    w.record("robot_state", {"data": {"joint_names": ["LCY"], "q": [0.1]}})
    w.close()
    with open(path, "rb") as f:
        tfs = [json.loads(m.data) for _s, _c, m in make_reader(f).iter_messages(topics=["/robot/tf"], log_time_order=False)]
    base = tfs[-1]["transforms"][0]
    assert (base["parent_frame_id"], base["child_frame_id"]) == ("world", "executed/PELVIS")
    assert base["translation"]["z"] == 0.9
