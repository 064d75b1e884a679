"""A real job's audit file, end to end: submit -> plan -> approve -> dispatch -> executed.

The real service (``regrasp serve``: API, SQLite store, worker process, audit
process, zenoh robot bridge) runs against ``regrasp controller-sim`` on a private
loopback endpoint, with the service tests' rig (tests/service/conftest.py) and
their ``stand`` handler: a real, gate-valid one-second plan that holds the
upright stance. The job's MCAP file, downloaded through the API, must hold the
request, the plan, the approval, the gate verdict, the dispatched segments and
the robot state echoed back, in that order, on a hash chain recomputed here from
the documented formula (docs/audit.md) and ending at the head stored with the job;
``regrasp audit verify --head`` must say intact.
"""

from __future__ import annotations

import hashlib
import io
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterator

import httpx
import numpy as np
import pytest
from mcap.reader import make_reader

from schemas.plan import plan_sha256
from tests.service.conftest import (
    ROOT,
    Server,
    free_port,
    start_controller_sim,
    stop_process,
    submit_approved_plan,
    wait_controller_alive,
    wait_state,
)

#: Executions on the simulated controller in wall-clock time (a 2 s watchdog, a 3 s zenoh lease): a failure
#: while the VM's host paused the guest for 0.5 s or more measured the host, and the test runs again.
pytestmark = pytest.mark.host_pauses(limit_s=0.5)
#: Contract states of a plan job that runs to the end, in order (docs/contract.md section 5).
PLAN_JOB_STATES = ["queued", "planning", "planned", "approved", "dispatching", "executing", "succeeded"]
CONTROLLER_UP_TIMEOUT_S = 60.0
JOB_TIMEOUT_S = 60.0
AUDIT_CLOSED_TIMEOUT_S = 30.0
#: The simulated controller starts in, and the plan holds, the stance posture.
ECHO_TOLERANCE_RAD = 1e-3
#: Documented input of a record's digest (service/audit/chain.py, docs/audit.md), recomputed here.
CHAIN_FORMAT = "regrasp.audit/1"
GENESIS = "0" * 64
MCAP_MAGIC = b"\x89MCAP0\r\n"


def _digest(seq: int, topic: str, schema: str, log_time: int, publish_time: int, data: bytes) -> str:
    header = json.dumps({"seq": seq, "topic": topic, "schema": schema, "log_time": log_time,
                         "publish_time": publish_time}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(f"{CHAIN_FORMAT}\n{header}\n".encode() + data).hexdigest()


class AuditedJob:
    """One executed job: its final view, the downloaded audit file and that file's messages in write order."""

    def __init__(self, job: dict[str, Any], path: Path) -> None:
        self.job = job
        self.path = path
        self.messages: list[dict[str, Any]] = []
        with open(path, "rb") as f:
            for schema, channel, msg in make_reader(f).iter_messages(log_time_order=False):
                self.messages.append({"topic": channel.topic, "schema": schema.name, "log_time": msg.log_time,
                                      "publish_time": msg.publish_time, "sequence": msg.sequence,
                                      "data": msg.data, "body": json.loads(msg.data)})
        #: The /audit/events records: (index among all messages, kind, payload).
        self.events = [(i, m["body"]["kind"], m["body"]["payload"]) for i, m in enumerate(self.messages)
                       if m["topic"] == "/audit/events"]
        self.survey: AuditedJob | None = None  # the survey job audited beside a plan job

    def of(self, kind: str) -> list[tuple[int, dict[str, Any]]]:
        return [(i, p) for i, k, p in self.events if k == kind]

    def one(self, kind: str) -> tuple[int, dict[str, Any]]:
        found = self.of(kind)
        assert len(found) == 1, f"{len(found)} {kind!r} records; kinds: {[k for _, k, _ in self.events]}"
        return found[0]


def _download_closed(client: httpx.Client, job_id: str, path: Path) -> Path:
    """The job's audit file once the audit process has closed it (after the terminal state)."""
    deadline = time.monotonic() + AUDIT_CLOSED_TIMEOUT_S
    while True:
        audit = client.get(f"/v1/jobs/{job_id}/audit")
        # A closed MCAP file ends with the magic bytes after its footer; an open one does not.
        if audit.status_code == 200 and audit.content.endswith(MCAP_MAGIC):
            path.write_bytes(audit.content)
            return path
        assert time.monotonic() < deadline, f"the audit file of {job_id} was never closed ({audit.status_code})"
        time.sleep(0.2)


def _byte_in_chunk_holding(path: Path, needle: bytes) -> int:
    """Offset of a byte in the middle of the compressed records of the chunk whose records hold ``needle``."""
    import zstandard
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk

    raw = path.read_bytes()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    for index in summary.chunk_indexes:
        end = index.chunk_start_offset + index.chunk_length
        chunk = Chunk.read(ReadDataStream(io.BytesIO(raw[index.chunk_start_offset + 9:end])))
        assert chunk.compression == "zstd"
        if needle in zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size):
            return end - len(chunk.data) + len(chunk.data) // 2
    raise AssertionError(f"no chunk holds {needle!r}")


@pytest.fixture(scope="module")
def audited(tmp_path_factory: pytest.TempPathFactory) -> Iterator[AuditedJob]:
    port = free_port()
    srv = Server(tmp_path_factory.mktemp("audit-e2e"), workers=1, bridge_port=port).start()
    sim = None
    try:
        sim = start_controller_sim(srv.data_dir, port, speed=1)
        wait_controller_alive(srv, sim, CONTROLLER_UP_TIMEOUT_S)
        job_id = submit_approved_plan(srv, {"scenario": "stand-1", "seed": 7}, JOB_TIMEOUT_S)
        with srv.client("alice") as alice, srv.client("bob") as bob:
            r = bob.post(f"/v1/jobs/{job_id}/dispatch")
            assert r.status_code == 202, r.text
            done = wait_state(bob, job_id, {"succeeded", "aborted", "rejected", "failed"}, JOB_TIMEOUT_S)
            assert done["state"] == "succeeded", (done["message"], done["error"])
            path = _download_closed(bob, job_id, srv.data_dir / "downloaded.mcap")
            job = bob.get(f"/v1/jobs/{job_id}").json()
            # A survey job (the test handler's quick document) is audited as well.
            r = alice.post("/v1/jobs", json={"kind": "survey", "request": {"scenario": "quick", "seed": 3}})
            assert r.status_code == 202, r.text
            survey = wait_state(alice, r.json()["id"], {"succeeded", "failed"}, JOB_TIMEOUT_S)
            assert survey["state"] == "succeeded", survey["error"]
            survey_path = _download_closed(alice, survey["id"], srv.data_dir / "survey.mcap")
            survey = alice.get(f"/v1/jobs/{survey['id']}").json()
        audited_job = AuditedJob(job, path)
        audited_job.survey = AuditedJob(survey, survey_path)
        yield audited_job
    finally:
        if sim is not None:
            stop_process(sim)
        srv.stop()


def test_the_chain_is_whole_and_ends_at_the_stored_head(audited: AuditedJob) -> None:
    prev = GENESIS
    for seq, m in enumerate(audited.messages):
        assert m["sequence"] == seq and m["body"]["audit"] == {"seq": seq, "prev": prev}, (seq, m["topic"])
        prev = _digest(seq, m["topic"], m["schema"], m["log_time"], m["publish_time"], m["data"])
    kinds = [k for _, k, _ in audited.events]
    assert kinds[0] == "audit.open" and kinds[-1] == "audit.close" and kinds.count("audit.close") == 1
    assert audited.events[0][2]["job_id"] == audited.job["id"]
    # The stored head is the last record's before the closing seal (the seal adds no history).
    before_close = audited.messages[-1]["body"]["audit"]["prev"]
    assert audited.job["audit_head"] == before_close


def test_regrasp_audit_verify_says_intact_and_catches_one_changed_byte(audited: AuditedJob, tmp_path: Path) -> None:
    def verify(path: Path, head: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "service.cli.main", "audit", "verify", str(path), "--head", head],
                              cwd=ROOT, capture_output=True, text=True, timeout=120)

    ok = verify(audited.path, audited.job["audit_head"])
    assert ok.returncode == 0 and "INTACT" in ok.stdout, ok.stdout + ok.stderr
    # One byte changed in the compressed chunk that names the approver: the file no longer holds.
    raw = audited.path.read_bytes()
    at = _byte_in_chunk_holding(audited.path, b'"approved_by":"bob"')
    edited = tmp_path / "edited.mcap"
    edited.write_bytes(raw[:at] + bytes([raw[at] ^ 0x20]) + raw[at + 1:])
    bad = verify(edited, audited.job["audit_head"])
    assert bad.returncode == 1 and "BROKEN" in bad.stdout, bad.stdout + bad.stderr


def test_every_state_change_is_recorded_in_order(audited: AuditedJob) -> None:
    states = [p["state"] for _, p in audited.of("state")]
    assert states == PLAN_JOB_STATES
    assert all(p["job_id"] == audited.job["id"] for _, p in audited.of("state"))


def test_request_plan_and_approval_bind_to_the_same_plan(audited: AuditedJob) -> None:
    job = audited.job
    i_req, request = audited.one("request")
    assert request["kind"] == "plan" and request["submitter"] == "alice"
    assert request["request"] == {"scenario": "stand-1", "seed": 7}

    i_plan, plan = audited.one("plan")
    document = plan["document"]
    assert document == job["result"]  # the full plan as the job holds it
    assert document["status"] == "solved" and len(document["trajectory"]) > 100
    assert plan["plan_sha256"] == plan_sha256(document) == job["plan_sha256"]

    i_ok, approval = audited.one("approval")
    assert approval["approved_by"] == "bob" and approval["approved_by"] != request["submitter"]
    assert approval["plan_sha256"] == plan_sha256(document)
    assert approval["expires_at"] > approval["approved_at"]
    assert i_req < i_plan < i_ok


def test_the_gate_passed_the_approved_plan_before_anything_was_sent(audited: AuditedJob) -> None:
    sha = audited.job["plan_sha256"]
    i_ok, _ = audited.one("approval")
    i_gate, gate = audited.one("gate")  # the bridge's verdict, as it was given
    assert gate["data"]["passed"] is True and gate["data"]["plan_sha256"] == sha
    first_segment = min(i for i, _ in audited.of("segment"))
    assert i_ok < i_gate < first_segment
    # The outcome repeats the verdict with the terminal state.
    i_verdict, verdict = audited.one("gate_verdict")
    assert verdict["verdict"]["passed"] is True and verdict["verdict"]["plan_sha256"] == sha
    i_end = next(i for i, p in audited.of("state") if p["state"] == "succeeded")
    assert i_verdict > i_end > first_segment


def test_dispatched_segments_cover_the_plan_with_contiguous_seq(audited: AuditedJob) -> None:
    document = audited.one("plan")[1]["document"]
    _, dispatching = audited.one("dispatching")
    count = dispatching["data"]["segments"]
    assert dispatching["data"]["points"] == len(document["trajectory"])
    assert dispatching["data"]["plan_sha256"] == audited.job["plan_sha256"]
    sent = [p["data"] for _, p in audited.of("segment") if "segment_index" in p["data"]]
    assert [s["segment_index"] for s in sent] == list(range(count))
    assert all(s["segment_count"] == count and s["job_id"] == audited.job["id"] for s in sent)
    seqs = [s["seq"] for s in sent]
    assert seqs == list(range(dispatching["data"]["first_seq"], dispatching["data"]["first_seq"] + count))
    # Every point of the plan went out once, in order, each segment at most 1 s (docs/contract.md section 6).
    assert [s["first_index"] for s in sent] == list(np.cumsum([0] + [s["points"] for s in sent[:-1]]))
    assert sum(s["points"] for s in sent) == len(document["trajectory"])
    assert all((s["points"] - 1) * document["dt_s"] <= 1.0 + 1e-9 for s in sent)
    # The controller acknowledged each of them.
    acked = {p["data"]["seq"] for _, p in audited.of("segment") if p["data"].get("acknowledged")}
    assert acked == set(seqs)


def test_robot_state_echoes_follow_the_plan(audited: AuditedJob) -> None:
    document = audited.one("plan")[1]["document"]
    names = document["robot"]["joint_names"]
    planned_q = np.array(document["trajectory"][0]["q"])
    echoes = audited.of("robot_state")
    assert len(echoes) >= 3, "a 1 s execution echoes the robot state every 0.1 s"
    first_segment = min(i for i, _ in audited.of("segment"))
    i_finished, finished = audited.one("finished")
    assert finished["data"]["status"] == "succeeded"
    for i, echo in echoes:
        assert first_segment < i < i_finished
        assert echo["data"]["joint_names"] == names
        assert np.max(np.abs(np.array(echo["data"]["q"]) - planned_q)) < ECHO_TOLERANCE_RAD
    # Each echo is also an executed joint state for Foxglove, beside the plan's own playback.
    # Each measured sample an echo carries (one, or the batch under ``samples``) is one executed joint state.
    executed = [m["body"] for m in audited.messages if m["topic"] == "/robot/joint_states"]
    samples = [s for _, echo in echoes for s in (echo["data"].get("samples") or [echo["data"]])]
    assert len(executed) == len(samples) > len(echoes)
    for s in samples:
        assert np.max(np.abs(np.array(s["q"]) - planned_q)) < ECHO_TOLERANCE_RAD
    assert [j["name"] for j in executed[0]["joints"]] == names
    topics = {m["topic"]: m["schema"] for m in audited.messages}
    assert topics["/plan/joint_states"] == topics["/robot/joint_states"] == "foxglove.JointStates"
    assert topics["/robot_description"] and topics["/plan/markers/support"] == "foxglove.SceneUpdate"


def test_a_survey_job_records_its_request_and_survey_document(audited: AuditedJob) -> None:
    sv = audited.survey
    assert sv is not None
    (i_req, req), (i_doc, doc) = sv.one("request"), sv.one("survey")
    assert req["kind"] == "survey" and req["request"]["scenario"] == "quick" and req["request"]["seed"] == 3
    assert i_req < i_doc
    assert doc["document"] == sv.job["result"]
    states = [p["state"] for _, p in sv.of("state")]
    assert states == ["queued", "planning", "succeeded"]
    assert not sv.of("plan") and not sv.of("approval")
    assert sv.job["audit_head"] == sv.messages[-1]["body"]["audit"]["prev"]
