"""Audit pump throughput: job events per second the service's pump turns into audit records.

A real SQLite job store (a file, as ``regrasp serve`` uses) holds a planned job and ``--events`` bridge
``robot_state`` events of one measured joint state each (a bridge reporting every state on its own, the
heaviest arrangement); the pump (``service.audit.pump.JobAuditor``) then runs until it has recorded them
all. Prints the events per second, the time the pump takes per event, and the time spent in the job store.
Target: well above the 66 events per second that a controller at 1x reporting each state would send.
Run: ``python benchmarks/bench_audit_pump.py [--events 600] [--plan-s 10]``.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from schemas.plan import canonical_json  # noqa: E402
from service.audit.pump import JobAuditor  # noqa: E402
from service.store import JobStore, make_engine, migrate  # noqa: E402
from tests.bridge.plans import build_plan  # noqa: E402  (a realistic plan made with the planner)


class TimedStore(JobStore):
    """The job store, with the time spent in it added up."""

    spent_s = 0.0

    def __getattribute__(self, name: str):  # noqa: ANN204 - wraps every public method
        attr = super().__getattribute__(name)
        if name.startswith("_") or not callable(attr) or name == "engine":
            return attr

        def timed(*a, **k):  # noqa: ANN002, ANN003, ANN202
            t0 = time.perf_counter()
            try:
                return attr(*a, **k)
            finally:
                type(self).spent_s += time.perf_counter() - t0
        return timed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=600, help="robot_state events to record")
    ap.add_argument("--plan-s", type=float, default=10.0, help="plan duration")
    args = ap.parse_args()
    plan = build_plan({"RSP": -0.4, "REP": -0.3}, duration_s=args.plan_s)
    text = canonical_json(plan).decode()
    sha = hashlib.sha256(text.encode()).hexdigest()
    names, traj = plan["robot"]["joint_names"], plan["trajectory"]
    with tempfile.TemporaryDirectory() as tmp:
        engine = make_engine(f"sqlite:///{tmp}/jobs.sqlite")
        migrate(engine)
        store = TimedStore(engine)
        job_id = "bench-pump"
        store.create(job_id=job_id, kind="plan", submitter="alice", request={"scenario": "upright"},
                     request_sha256="1" * 64, idempotency_key=None, provenance={})
        store.claim("runner", 1, 60.0)
        store.finish_planning(job_id, "runner", "planned", message="planned", planning_s=1.0, result_text=text,
                              extra={"plan_sha256": sha})
        auditor = JobAuditor(store, Path(tmp) / "audit")
        auditor.audit_dir.mkdir()
        auditor.pump_once()  # the plan and its playback: not what is measured
        for k in range(args.events):
            i = min(k * 3, len(traj) - 1)
            store.add_event(job_id, "bridge", data={"event": "robot_state", "payload": {
                "stamp": 1000.0 + k / 66.0, "joint_names": names, "q": traj[i]["q"], "index": i}})
        TimedStore.spent_s = 0.0
        started = time.perf_counter()
        done = 0
        while done < args.events:
            done += auditor.pump_once()
        elapsed = time.perf_counter() - started
        auditor.stop()
        engine.dispose()
    print(f"{args.events} robot_state events recorded in {elapsed:.2f} s: {args.events / elapsed:.0f} events/s, "
          f"{elapsed / args.events * 1000:.2f} ms per event, of which {TimedStore.spent_s / args.events * 1000:.2f} ms "
          f"in the job store")


if __name__ == "__main__":
    main()
