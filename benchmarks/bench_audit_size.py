"""Audit file size: megabytes per minute of plan, for a plan job with its execution.

Builds a plan of ``--seconds`` (default 60 s at 5 ms, many joints moving, the object held)
and writes its audit file as the service does: the job's events in a real SQLite store,
turned into records by the service's audit pump code (``service.audit.pump.records_for_event``)
and written by ``AuditWriter`` at the events' times: request, planning, the plan (its stored
canonical text), approval, the gate's verdict, dispatch, every 0.25 s segment sent and
acknowledged, the robot state reported every 0.1 s with the 67 states per second measured since the
last report, the plan replayed on the execution's timeline (``/executed_plan/``), the end. Prints the file size, MB per
minute of plan, the bytes per topic before compression, and the write time.
Target (docs/audit.md): a 60 s plan with its execution under 20 MB.
Run: ``python benchmarks/bench_audit_size.py [--seconds 60] [--compression zstd|none]``.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
import time
from collections import defaultdict
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mcap.reader import make_reader  # noqa: E402

from schemas.plan import canonical_json  # noqa: E402
from service.audit import AuditSettings, AuditWriter, verify  # noqa: E402
from service.audit.pump import records_for_event  # noqa: E402
from service.store import JobStore, make_engine, migrate  # noqa: E402
from tests.bridge.plans import build_plan  # noqa: E402  (a realistic plan made with the planner)

#: Joints moved by the benchmark's plan (arms, waist, neck: most of the body changes at every point).
MOVES = {"RSP": -0.8, "REP": -0.4, "RSR": -0.2, "RSY": 0.2, "RWRY": 0.3, "LSP": -0.5, "LEP": -0.3, "LSR": 0.2,
         "LSY": -0.2, "WY": 0.3, "WP": 0.05, "HY": 0.2, "HP": 0.1}
SEGMENT_S = 0.25
ROBOT_STATE_PERIOD_S = 0.1
#: Measured joint states kept per second of motion, reported in batches: what the simulated controller
#: publishes by default at up to 3x (a 200 Hz control loop, every third tick; CONTRACT 7: at least 50).
MEASURED_RATE_HZ = 67


def _job(store: JobStore, plan: dict[str, Any]) -> tuple[str, str]:
    text = canonical_json(plan).decode()
    sha = hashlib.sha256(text.encode()).hexdigest()
    job_id = "bench-audit"
    store.create(job_id=job_id, kind="plan", submitter="alice", request={"scenario": "upright"},
                 request_sha256="1" * 64, idempotency_key=None, provenance={})
    store.claim("runner", 1, 60.0)
    store.finish_planning(job_id, "runner", "planned", message="planned", planning_s=1.0, result_text=text,
                          extra={"plan_sha256": sha})
    return job_id, sha


def _timeline(store: JobStore, job_id: str, sha: str, plan: dict[str, Any]) -> list[dict[str, Any]]:
    """The job's events: its real ones up to planned, then the rest at the times they would happen."""
    names = plan["robot"]["joint_names"]
    traj = plan["trajectory"]
    duration = traj[-1]["t"]
    events: list[dict[str, Any]] = list(store.events_after(job_id))  # queued, planning, planned
    planned = events[-1]["at"]
    next_id = events[-1]["id"] + 1

    def add(at: datetime, kind: str, *, state: str | None = None, message: str = "", data: dict | None = None) -> None:
        events.append({"id": next_id + len(events), "job_id": job_id, "kind": kind, "state": state, "at": at,
                       "message": message, "progress": None, "data": data or {}})

    given = planned + timedelta(seconds=20)
    approval = {"approved_by": "bob", "approved_at": given.isoformat(),
                "expires_at": (given + timedelta(seconds=600)).isoformat(), "plan_sha256": sha}
    add(given, "state", state="approved", data={"approval": approval})
    start = given + timedelta(seconds=10)
    add(start, "state", state="dispatching", data={"by": "carol", "plan_sha256": sha})
    verdict = {"passed": True, "check": None, "plan_sha256": sha, "samples": 2 * len(traj), "message": "every check passed",
               "stats": {"com_margin": {"min_margin_m": plan["min_margin_m"]}}}
    add(start, "bridge", data={"event": "gate", "payload": verdict})
    per = int(SEGMENT_S / plan["dt_s"]) + 1
    segments = list(range(0, len(traj), per))
    add(start, "bridge", data={"event": "dispatching", "payload": {"job_id": job_id, "segments": len(segments),
                                                                    "points": len(traj), "plan_sha256": sha}})
    add(start, "state", state="executing")
    for k, first in enumerate(segments):
        at = start + timedelta(seconds=max(0.0, first * plan["dt_s"] - 0.5))
        seg = {"job_id": job_id, "seq": k, "segment_index": k, "segment_count": len(segments), "first_index": first,
               "points": min(per, len(traj) - first), "t_from_start": first * plan["dt_s"]}
        add(at, "bridge", data={"event": "segment", "payload": seg})
        add(at + timedelta(milliseconds=2), "bridge", data={"event": "segment", "payload": {
            "job_id": job_id, "seq": k, "acknowledged": True}})
    per_report = round(ROBOT_STATE_PERIOD_S * MEASURED_RATE_HZ)
    for k in range(int(duration / ROBOT_STATE_PERIOD_S) + 1):
        samples = []
        for j in range(per_report):
            t = k * ROBOT_STATE_PERIOD_S + (j - per_report + 1) / MEASURED_RATE_HZ
            if t < 0:
                continue
            i = min(int(round(t / plan["dt_s"])), len(traj) - 1)
            samples.append({"stamp": 1000.0 + t, "q": traj[i]["q"], "index": i})
        add(start + timedelta(seconds=k * ROBOT_STATE_PERIOD_S), "bridge", data={"event": "robot_state", "payload": {
            "joint_names": names, "samples": samples}})
    end = start + timedelta(seconds=duration + 0.1)
    add(end, "bridge", data={"event": "finished", "payload": {"status": "succeeded", "reason": None}})
    add(end, "state", state="succeeded", message="executed", data={"execution": True, "verdict": verdict})
    events.sort(key=lambda e: e["at"])
    return events


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="plan duration")
    ap.add_argument("--compression", choices=["zstd", "none"], default="zstd")
    args = ap.parse_args()
    plan = build_plan(MOVES, duration_s=args.seconds - 0.1, mass_kg=4.0, holding="right", threshold_m=0.02)
    duration = plan["trajectory"][-1]["t"]
    with tempfile.TemporaryDirectory() as tmp:
        engine = make_engine(f"sqlite:///{tmp}/jobs.sqlite")
        migrate(engine)
        store = JobStore(engine)
        job_id, sha = _job(store, plan)
        job = store.get(job_id) or {}
        plan_mb = len(store.result_text(job_id) or "") / 1e6
        path = Path(tmp) / "job.mcap"
        started = time.perf_counter()
        writer = AuditWriter(path, job_id, robot_name="hrp5p", settings=AuditSettings(compression=args.compression))
        for event in _timeline(store, job_id, sha, plan):
            for kind, payload, at_ns in records_for_event(event, job, store):
                writer.record(kind, payload, at_ns)
        head = writer.close()
        elapsed = time.perf_counter() - started
        size_mb = path.stat().st_size / 1e6
        by_topic: dict[str, list[int]] = defaultdict(lambda: [0, 0])
        with open(path, "rb") as f:
            for _s, channel, msg in make_reader(f).iter_messages(log_time_order=False):
                by_topic[channel.topic][0] += 1
                by_topic[channel.topic][1] += len(msg.data)
        status = verify(path, head).status
        engine.dispose()
    print(f"plan: {len(plan['trajectory'])} points at 5 ms ({duration:.1f} s), {len(plan['robot']['joint_names'])} joints, "
          f"{len(MOVES)} moving; canonical JSON {plan_mb:.1f} MB")
    print(f"audit file ({args.compression}): {size_mb:.2f} MB -> {size_mb / (duration / 60):.2f} MB per minute of plan "
          f"(plan and its execution); written in {elapsed:.2f} s; verify: {status}")
    print("bytes per topic before compression:")
    for topic, (count, nbytes) in sorted(by_topic.items(), key=lambda kv: -kv[1][1]):
        print(f"  {topic:<24s} {count:6d} messages {nbytes / 1e6:8.2f} MB")
    print(f"total before compression: {sum(b for _, b in by_topic.values()) / 1e6:.2f} MB; target: < 20 MB for 60 s")


if __name__ == "__main__":
    main()
