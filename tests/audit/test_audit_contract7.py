"""Audit files as the contract's section 7 has them (docs/audit.md): event times, /plan/ and /robot/
topics, markers that carry their own instant only, zstd chunks, one plan copy, one download after a
restart, a damaged length field read as broken, the layout and the log levels.

The job side runs for real: a SQLite job store and the service's audit pump (JobAuditor).
"""

from __future__ import annotations

import hashlib
import json
import struct
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from schemas.plan import canonical_json
from service.audit import AuditSettings, AuditWriter, ExitCode, verify
from service.audit.pump import JobAuditor
from service.store import JobStore, make_engine, migrate

from .conftest import tiny_plan, write_sample

NS = 1_000_000_000


def _messages(path: Path) -> list[dict[str, Any]]:
    with open(path, "rb") as f:
        return [{"topic": c.topic, "schema": s.name, "log_time": m.log_time, "data": m.data,
                 "body": json.loads(m.data)}
                for s, c, m in make_reader(f).iter_messages(log_time_order=False)]


def _events(path: Path) -> list[dict[str, Any]]:
    return [m for m in _messages(path) if m["topic"] == "/audit/events"]


def _ns(at: datetime) -> int:
    return int(round(at.timestamp() * 1e6)) * 1000


def _plan_doc(n: int = 201) -> dict[str, Any]:
    plan = tiny_plan(n)
    plan.update({"schema": "regrasp.plan/1", "status": "solved"})
    plan["robot"]["urdf_sha256"] = "0" * 64
    for point in plan["trajectory"]:
        point.update({"holding": "none", "object_pose": [0.5, 0.0, 0.8, 0.0, 0.0, 0.0, 1.0],
                      "zmp": [point["com"][0], 0.0]})
    plan["scenario"] = {"object": {"shape": "box", "size": [0.3, 0.2, 0.2]},
                        "tables": [{"name": "table", "pose": [0.6, 0.0, 0.4, 0, 0, 0, 1], "size": [0.5, 0.8, 0.8]}]}
    return plan


class Job:
    """A plan job in a real SQLite store, moved through its states as the service moves it."""

    def __init__(self, tmp: Path, plan: dict[str, Any]) -> None:
        self.engine = make_engine(f"sqlite:///{tmp / 'jobs.sqlite'}")
        migrate(self.engine)
        self.store = JobStore(self.engine)
        self.audit_dir = tmp / "audit"
        self.audit_dir.mkdir()
        self.id = "job-" + hashlib.sha256(str(tmp).encode()).hexdigest()[:8]
        self.text = canonical_json(plan).decode()
        self.sha = hashlib.sha256(self.text.encode()).hexdigest()
        self.store.create(job_id=self.id, kind="plan", submitter="alice", request={"scenario": "upright"},
                          request_sha256="1" * 64, idempotency_key=None, provenance={})

    def plan(self) -> None:
        owner = "runner-1"
        assert self.store.claim(owner, 1, 60.0)
        assert self.store.finish_planning(self.id, owner, "planned", message="planned", planning_s=0.1,
                                          result_text=self.text, extra={"plan_sha256": self.sha})

    def approve(self, given_at: datetime) -> None:
        expires = given_at + timedelta(seconds=600)
        approval = {"approved_by": "bob", "approved_at": given_at.isoformat(), "expires_at": expires.isoformat(),
                    "plan_sha256": self.sha}
        assert self.store.transition(self.id, ["planned"], "approved", data={"approval": approval},
                                     approved_by="bob", approved_at=given_at, approval_expires_at=expires,
                                     approved_sha256=self.sha)

    def expire(self) -> None:
        self.store.update_fields(self.id, approval_expires_at=datetime.now(timezone.utc) - timedelta(seconds=1))
        assert self.store.expire_approvals(self.id) == [self.id]

    def end(self) -> None:
        assert self.store.transition(self.id, ["planned", "approved"], "canceled", message="canceled by alice")

    def auditor(self) -> JobAuditor:
        auditor = JobAuditor(self.store, self.audit_dir)
        auditor._cursor = auditor._start_cursor()
        return auditor

    def row(self) -> dict[str, Any]:
        row = self.store.get(self.id)
        assert row is not None
        return row


@pytest.fixture()
def job(tmp_path: Path) -> Job:
    return Job(tmp_path, _plan_doc())


# ----------------------------------------------------------------------------- log times


def test_an_approval_is_logged_at_the_moment_it_was_given(job: Job) -> None:
    auditor = job.auditor()
    job.plan()
    given = datetime.now(timezone.utc) - timedelta(seconds=11.3)  # written well after it was given
    job.approve(given)
    job.end()
    auditor.pump_once()
    path = Path(job.row()["audit_path"])
    events = _events(path)
    approval = [m for m in events if m["body"]["kind"] == "approval"]
    assert len(approval) == 1
    assert approval[0]["log_time"] == _ns(given)
    # Every event record carries the time of its event row, not the time the pump wrote it.
    rows = {e["id"]: e for e in job.store.events_after(job.id)}
    for m in events:
        payload = m["body"]["payload"]
        if m["body"]["kind"] in ("state", "request", "plan"):
            assert m["log_time"] == _ns(rows[payload["event_id"]]["at"]), m["body"]["kind"]


# ----------------------------------------------------------------------------- topics, markers


def test_the_plan_playback_is_under_plan_and_the_robot_state_under_robot(tmp_path: Path, hrp5p_urdf: str) -> None:
    path = tmp_path / "a.mcap"
    w = AuditWriter(path, "j", urdf_text=hrp5p_urdf)
    w.plan_playback(_plan_doc())
    w.record("robot_state", {"data": {"joint_names": ["LCY"], "q": [0.1]}})
    w.close()
    topics = {m["topic"]: m["schema"] for m in _messages(path)}
    plan = {t for t in topics if t.startswith("/plan/")}
    assert {"/plan/joint_states", "/plan/tf", "/plan/markers/com", "/plan/markers/zmp", "/plan/markers/object",
            "/plan/markers/support", "/plan/markers/scene", "/plan/stability"} <= plan
    assert {"/robot/joint_states", "/robot/tf"} <= set(topics)
    # Nothing of the plan's playback outside /plan/, nothing the robot reported inside it.
    assert {t for t, s in topics.items() if s in ("foxglove.JointStates", "foxglove.SceneUpdate")} <= \
        plan | {"/robot/joint_states"}
    robot_tf = [m["body"] for m in _messages(path) if m["topic"] == "/robot/tf"]
    assert all(t["child_frame_id"].startswith("executed/") for b in robot_tf for t in b["transforms"])


def test_a_marker_message_carries_only_its_new_data(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    w = AuditWriter(path, "j")
    w.plan_playback(_plan_doc(801))  # 4 s at 5 ms: 201 playback samples
    w.close()
    com = [m for m in _messages(path) if m["topic"] == "/plan/markers/com"]
    assert len(com) == 201
    for m in com:
        (entity,) = m["body"]["entities"]
        assert len(entity["spheres"]) == 1
        assert sum(len(line["points"]) for line in entity["lines"]) == 2  # the drop line; no trace so far
    sizes = [len(m["data"]) for m in com]
    assert max(sizes) < 1.2 * min(sizes)  # the last message is no bigger than the first (up to float digits)
    # The CoM now is where the plan has it at that instant.
    plan = _plan_doc(801)
    last = com[-1]["body"]["entities"][0]["spheres"][0]["pose"]["position"]
    assert [last["x"], last["y"], last["z"]] == plan["trajectory"][-1]["com"]
    for topic in ("/plan/markers/zmp", "/plan/markers/object"):
        sizes = [len(m["data"]) for m in _messages(path) if m["topic"] == topic]
        assert len(sizes) == 201 and max(sizes) < 1.2 * min(sizes), topic


def test_zmp_object_and_table_markers(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    w = AuditWriter(path, "j")
    w.plan_playback(_plan_doc(21))
    w.close()
    msgs = _messages(path)
    (scene,) = [m["body"] for m in msgs if m["topic"] == "/plan/markers/scene"]
    table = next(e for e in scene["entities"] if e["id"] == "table/table")
    assert table["cubes"][0]["size"] == {"x": 0.5, "y": 0.8, "z": 0.8}
    obj = [m["body"]["entities"][0] for m in msgs if m["topic"] == "/plan/markers/object"][0]
    assert obj["cubes"][0]["size"] == {"x": 0.3, "y": 0.2, "z": 0.2}
    assert obj["cubes"][0]["pose"]["position"] == {"x": 0.5, "y": 0.0, "z": 0.8}
    point = _plan_doc(21)["trajectory"][12]  # playback sample 3 at 50 Hz (every 4th point at 5 ms)
    zmp = [m["body"]["entities"][0] for m in msgs if m["topic"] == "/plan/markers/zmp"]
    assert zmp[3]["cylinders"][0]["pose"]["position"]["x"] == point["zmp"][0]
    stab = [m["body"] for m in msgs if m["topic"] == "/plan/stability"]
    assert stab[3]["index"] == 12
    # The square polygon's edge is 0.12 m from x = 0: the ZMP margin of (x, 0) is 0.12 - x.
    assert stab[3]["zmp_margin_m"] == pytest.approx(0.12 - point["zmp"][0])
    assert stab[3]["margin_m"] == point["margin_m"]


# ----------------------------------------------------------------------------- compression, copies


def test_chunks_are_compressed_with_zstd(job: Job) -> None:
    auditor = job.auditor()
    job.plan()
    job.end()
    auditor.pump_once()
    path = Path(job.row()["audit_path"])
    data = path.read_bytes()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.chunk_indexes
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
    # The plan's JSON is not readable in the file: it is inside compressed chunks.
    assert b'"trajectory"' not in data
    assert verify(path, job.row()["audit_head"]).exit_code == ExitCode.INTACT


def test_an_expired_approval_does_not_write_the_plan_again(job: Job) -> None:
    auditor = job.auditor()
    job.plan()
    job.approve(datetime.now(timezone.utc))
    job.expire()  # back to planned
    job.approve(datetime.now(timezone.utc))
    job.expire()
    job.end()
    auditor.pump_once()
    events = _events(Path(job.row()["audit_path"]))
    kinds = [m["body"]["kind"] for m in events]
    assert kinds.count("plan") == 1
    states = [m["body"]["payload"]["state"] for m in events if m["body"]["kind"] == "state"]
    assert states == ["queued", "planning", "planned", "approved", "planned", "approved", "planned", "canceled"]
    (plan,) = [m for m in events if m["body"]["kind"] == "plan"]
    # The stored canonical text is in the record as it is, byte for byte.
    assert job.text.encode() in plan["data"]
    joint_states = [m for m in _messages(Path(job.row()["audit_path"])) if m["topic"] == "/plan/joint_states"]
    assert len(joint_states) == 51  # one playback: 1 s at 50 Hz, both ends


# ----------------------------------------------------------------------------- restart


def test_a_job_continued_after_a_restart_downloads_all_its_records(job: Job) -> None:
    first = job.auditor()
    job.plan()
    first.pump_once()  # request, planning, planned + the plan: then the service dies (no close)
    cut = Path(job.row()["audit_path"])
    assert verify(cut).exit_code == ExitCode.UNFINISHED
    given = datetime.now(timezone.utc)
    job.approve(given)
    job.end()
    second = job.auditor()  # the restarted service's pump
    second.pump_once()
    row = job.row()
    served = Path(row["audit_path"])  # what GET /v1/jobs/{id}/audit serves
    assert served != cut and row["audit_closed"]
    result = verify(served, row["audit_head"])
    assert result.exit_code == ExitCode.INTACT, result.detail
    kinds = [m["body"]["kind"] for m in _events(served)]
    for kind in ("audit.open", "request", "plan", "continued", "approval", "audit.close"):
        assert kind in kinds, kind
    assert kinds.count("audit.open") == 1 and kinds.count("plan") == 1
    states = [m["body"]["payload"]["state"] for m in _events(served) if m["body"]["kind"] == "state"]
    assert states == ["queued", "planning", "planned", "approved", "canceled"]
    # The records of the cut file are carried over unchanged: the same bytes, the same chain.
    cut_msgs = [e.data for e in verify(cut, keep_raw=True).entries]  # an unfinished file: read by the verifier
    assert [m["data"] for m in _messages(served)[: len(cut_msgs)]] == cut_msgs
    (continued,) = [m["body"]["payload"] for m in _events(served) if m["body"]["kind"] == "continued"]
    assert continued["previous_file"] == cut.name and continued["carried_records"] == len(cut_msgs)


# ----------------------------------------------------------------------------- damaged length field


def _record_offsets(data: bytes) -> list[tuple[int, int]]:
    """(offset, opcode) of every top-level MCAP record, up to and including the footer."""
    pos, out = 8, []
    while pos + 9 <= len(data) - 8:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        out.append((pos, opcode))
        pos += 9 + length
    return out


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_one_flipped_bit_in_any_length_field_of_a_complete_file_is_broken(tmp_path: Path, hrp5p_urdf: str,
                                                                          compression: str) -> None:
    """Every bit of every top-level record's length (header, chunks, attachment, data end, summary, footer)."""
    path = tmp_path / "job.mcap"
    heads = write_sample(path, hrp5p_urdf, compression=compression)
    data = path.read_bytes()
    assert verify(path, heads[-1]).exit_code == ExitCode.INTACT
    records = _record_offsets(data)
    assert {0x01, 0x06, 0x09, 0x0F, 0x02} <= {op for _, op in records}  # header, chunk, attachment, data end, footer
    bad = tmp_path / "bad.mcap"
    for offset, opcode in records:
        length = struct.unpack_from("<Q", data, offset + 1)[0]
        for bit in (0, 1, 4, 12, 20, 33, 47, 63):  # low bits (a few bytes off) to high (past any file)
            damaged = bytearray(data)
            struct.pack_into("<Q", damaged, offset + 1, length ^ (1 << bit))
            bad.write_bytes(bytes(damaged))
            result = verify(bad)
            assert result.exit_code == ExitCode.BROKEN, (offset, hex(opcode), bit, result.detail)


def test_a_file_cut_short_is_still_unfinished(tmp_path: Path, hrp5p_urdf: str) -> None:
    path = tmp_path / "job.mcap"
    write_sample(path, hrp5p_urdf, compression="zstd")
    data = path.read_bytes()
    for keep in (len(data) // 3, len(data) // 2, len(data) - 40):
        cut = tmp_path / f"cut-{keep}.mcap"
        cut.write_bytes(data[:keep])
        assert verify(cut).exit_code == ExitCode.UNFINISHED, keep


# ----------------------------------------------------------------------------- Foxglove


def test_the_layout_is_attached_and_named_by_the_chain(tmp_path: Path) -> None:
    from service.audit.layout import LAYOUT_ATTACHMENT, layout_bytes

    path = tmp_path / "a.mcap"
    AuditWriter(path, "j").close()
    with open(path, "rb") as f:
        attachments = list(make_reader(f).iter_attachments())
    (layout,) = [a for a in attachments if a.name == LAYOUT_ATTACHMENT]
    assert layout.data == layout_bytes() and layout.media_type == "application/json"
    doc = json.loads(layout.data)
    panels = set(doc["configById"])
    assert {"3D!robot", "Plot!margin", "Plot!zmp", "Log!log"} <= panels
    paths = {p["value"] for k in ("Plot!margin", "Plot!zmp") for p in doc["configById"][k]["paths"]}
    assert {"/plan/stability.margin_m", "/plan/stability.zmp_margin_m"} <= paths
    opened = _events(path)[0]["body"]["payload"]
    assert opened["layout"]["sha256"] == hashlib.sha256(layout.data).hexdigest()


def test_log_levels_follow_severity(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    w = AuditWriter(path, "j", settings=AuditSettings(auto_visualize=False))
    w.record("state", {"state": "planning", "data": {}})
    w.record("state", {"state": "failed", "data": {"error": {"code": "INFEASIBLE"}}})
    w.record("state", {"state": "rejected", "data": {"by": "bob"}})
    w.record("state", {"state": "rejected", "data": {"execution": True, "verdict": {"passed": False}}})
    w.record("gate", {"data": {"passed": False, "check": "zmp"}})
    w.record("gate_verdict", {"verdict": {"passed": True}})
    w.record("state", {"state": "aborted", "data": {"reason": "stopped by an operator"}})
    w.record("progress", {"progress": 0.5})
    w.close()
    levels = [(m["body"]["message"].split(":")[0], m["body"]["level"]) for m in _messages(path) if m["topic"] == "/log"]
    assert [lv for _, lv in levels[1:]] == [2, 4, 3, 4, 4, 2, 4, 1]  # after the open record
