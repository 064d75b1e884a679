"""One timeline: the plan replayed under /executed_plan/ as the controller plays it, and measured joint states
at the controller's measurement times (publish_time), so that planned and measured robots overlap in time."""

from __future__ import annotations

import json

from mcap.reader import make_reader

from service.audit import AuditSettings, AuditWriter, RawJson, verify

from .conftest import tiny_plan

NS = 1_000_000_000
PLANNED_AT = 1_700_000_000 * NS
REPORT_LATENCY_NS = 3_000_000


def _plan(n: int = 400) -> dict:
    plan = tiny_plan(n)
    plan["schema"] = "regrasp.plan/1"
    return plan


def _execute(path, *, speed: float, stop_at: int | None = None, batch: int = 1, start_buffer_s: float = 0.0) -> dict:
    """A job planned at PLANNED_AT and executed 110 s later: robot_state reports every 0.1 s of the controller's
    clock, each with the states measured since the previous report (``batch`` of them)."""
    plan = _plan()
    w = AuditWriter(path, "job-1", robot_name="hrp5p", settings=AuditSettings(compression="none"),
                    clock_ns=lambda: PLANNED_AT)
    w.record("plan", {"document": RawJson(json.dumps(plan))}, PLANNED_AT)
    dt, n = plan["dt_s"], len(plan["trajectory"])
    controller_t0 = 5000.0  # the controller's monotonic clock at playback start (s)
    wall_t0 = PLANNED_AT + 110 * NS
    period = 0.1 / batch
    t, reports = -start_buffer_s, []
    last = stop_at if stop_at is not None else n - 1
    while True:
        index = max(0, min(last, int(round(t * speed / dt))))
        reports.append({"stamp": controller_t0 + t, "q": plan["trajectory"][index]["q"], "index": index})
        if index >= last:
            break
        t += period
    for k in range(0, len(reports), batch):
        group = reports[k:k + batch]
        reported = wall_t0 + int(round((group[-1]["stamp"] - controller_t0) * NS)) + REPORT_LATENCY_NS
        data = ({"joint_names": plan["robot"]["joint_names"], "samples": group} if batch > 1
                else {"joint_names": plan["robot"]["joint_names"], **group[0]})
        w.record("robot_state", {"data": data}, reported)
    w.close()
    return {"plan": plan, "reports": reports, "wall_t0": wall_t0, "controller_t0": controller_t0}


def _messages(path) -> dict[str, list]:
    out: dict[str, list] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append(message)
    return out


def test_the_plan_is_replayed_on_the_execution_timeline(tmp_path) -> None:
    path = tmp_path / "job.mcap"
    run = _execute(path, speed=2.0, start_buffer_s=0.3)
    m = _messages(path)
    assert verify(path).exit_code == 0
    planned = [x.log_time for x in m["/plan/joint_states"]]
    replayed = [x.log_time for x in m["/executed_plan/joint_states"]]
    measured = [x.log_time for x in m["/robot/joint_states"]]
    assert max(planned) < min(measured)  # the plan's own playback is at planning time ...
    assert min(replayed) < max(measured) and max(replayed) > min(measured)  # ... its replay overlaps the robot's
    # The replay runs at the controller's speed: the plan's 2 s in 1 s of the execution, its start where t = 0
    # was played (after the start buffer), within one report period.
    duration = run["plan"]["trajectory"][-1]["t"]
    assert abs((max(replayed) - min(replayed)) / NS - duration / 2.0) < 0.1
    assert abs(min(replayed) - run["wall_t0"]) < 0.1 * NS
    for topic in ("tf", "markers/com", "stability", "markers/support"):
        assert f"/executed_plan/{topic}" in m, topic


def test_robot_messages_carry_the_measurement_time(tmp_path) -> None:
    path = tmp_path / "job.mcap"
    run = _execute(path, speed=1.0, batch=5)
    m = _messages(path)
    states = m["/robot/joint_states"]
    assert len(states) == len(run["reports"])  # every measured state kept, batches included
    stamps = [r["stamp"] for r in run["reports"]]
    published = [x.publish_time for x in states]
    for k in range(1, len(states)):  # the controller's own intervals
        assert abs((published[k] - published[0]) / NS - (stamps[k] - stamps[0])) < 1e-6
    assert all(x.publish_time == x.log_time for x in states)
    assert len({x.publish_time for x in states}) == len(states)
    assert verify(path).exit_code == 0  # the chain covers publish_time too


def test_after_an_abort_the_replay_stops_where_the_robot_stopped(tmp_path) -> None:
    path = tmp_path / "job.mcap"
    _execute(path, speed=1.0, stop_at=150)
    m = _messages(path)
    replayed = [json.loads(x.data) for x in m["/executed_plan/stability"]]
    assert replayed and max(s["index"] for s in replayed) <= 150
    last_measured = max(x.log_time for x in m["/robot/joint_states"])
    assert max(x.log_time for x in m["/executed_plan/joint_states"]) <= last_measured + 1


def test_the_measured_cop_is_a_floor_marker_over_the_support_polygon(tmp_path) -> None:
    """The physics plant's balance sample: on /robot/balance for the plots, and its CoP as a floor marker
    (orange inside the polygon, red outside) that the shipped layout shows in the 3D panel."""
    from service.audit.layout import layout_bytes

    path = tmp_path / "job.mcap"
    w = AuditWriter(path, "job-1", robot_name="hrp5p", settings=AuditSettings(compression="none"),
                    clock_ns=lambda: PLANNED_AT)
    for k, (x, margin) in enumerate(((0.01, 0.05), (0.2, -0.03))):
        w.record("balance", {"data": {"cop": [x, 0.0], "cop_margin_m": margin, "foot_forces_n": {"left": 500.0,
                                                                                                  "right": 480.0}}},
                 PLANNED_AT + k * NS)
    w.close()
    m = _messages(path)
    markers = [json.loads(x.data) for x in m["/robot/markers/cop"]]
    assert len(markers) == 2
    discs = [u["entities"][0]["cylinders"][0] for u in markers]
    assert [d["pose"]["position"]["x"] for d in discs] == [0.01, 0.2]
    assert discs[0]["color"]["r"] == 1.0 and discs[1]["color"]["g"] < 0.2  # inside orange, outside red
    layout = json.loads(layout_bytes())
    assert layout["configById"]["3D!robot"]["topics"]["/robot/markers/cop"]["visible"] is True
    paths = [p["value"] for p in layout["configById"]["Plot!zmp"]["paths"]]
    assert "/robot/balance.cop_margin_m" in paths
