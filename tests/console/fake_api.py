"""A small in-memory fake of the job API (docs/contract.md section 5) for the console's browser tests.

It follows the contract's routes, roles, states and problem+json errors closely
enough to drive the page before (and independently of) the real service:
tokens ``planner-token-alice`` (planner), ``approver-token-bob`` (approver),
``operator-token-carol`` (operator), ``viewer-token-dan`` (no role: reads only),
``admin-token-erin`` (admin: every role); ``GET /v1/me`` tells a token's user and
roles (``me_enabled = False`` answers 404, as a service without it would). One
planned plan job submitted by alice and one finished survey job. Dispatch plays a
short execution (executing -> succeeded) with progress events on the SSE stream;
a stop ends it at once.
"""

from __future__ import annotations

import asyncio
import json
import math
import threading
import time
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles

from .openapi_check import DEVIATION_HEADER, ContractCheck, install

CONSOLE_DIR = Path(__file__).resolve().parents[2] / "service" / "console"
TOKENS = {
    "planner-token-alice": ("alice", {"planner"}),
    "approver-token-bob": ("bob", {"approver"}),
    "operator-token-carol": ("carol", {"operator"}),
    "viewer-token-dan": ("dan", set()),
    "admin-token-erin": ("erin", {"admin"}),
    "planner-approver-token-frank": ("frank", {"planner", "approver"}),
}
TERMINAL = {"succeeded", "failed", "canceled", "rejected", "aborted"}
EXECUTION_STEPS = 8
EXECUTION_STEP_S = 0.15
THRESHOLD_M = 0.06
POLYGON = [[0.125, -0.155], [0.125, 0.155], [0.05, 0.17], [-0.115, 0.17], [-0.115, -0.17], [0.05, -0.17]]


def _now() -> str:
    return datetime.now(timezone.utc).isoformat()


def _margin(x: float, y: float) -> float:
    """Signed distance to the edge of the convex polygon above (inside positive)."""
    best = math.inf
    n = len(POLYGON)
    for i in range(n):
        (x1, y1), (x2, y2) = POLYGON[i], POLYGON[(i + 1) % n]
        ex, ey = x2 - x1, y2 - y1
        length = math.hypot(ex, ey)
        d = ((y - y1) * ex - (x - x1) * ey) / length  # POLYGON is CCW: inside is left of each edge
        best = min(best, d)
    return best


def synthetic_plan() -> dict[str, Any]:
    dt = 0.005
    traj = []
    n = 400
    for i in range(n):
        s = i / (n - 1)
        x = 0.01 + 0.025 * math.sin(2 * math.pi * s)
        y = -0.09 * math.sin(math.pi * s)
        traj.append({"t": i * dt, "q": [0.0, 0.1 * s], "holding": "right" if 0.3 < s < 0.8 else "none",
                     "object_pose": [0.5, 0, 0.8, 0, 0, 0, 1], "com": [x, y, 0.85], "margin_m": _margin(x, y),
                     "zmp": [x, y]})
    return {
        "schema": "regrasp.plan/1", "status": "solved", "failure": None,
        "robot": {"name": "hrp5p", "urdf_sha256": "0" * 64, "joint_names": ["J0", "J1"]},
        "stance": {"name": "upright", "base_pose": [0, 0, 0.9, 0, 0, 0, 1], "feet": []},
        "scenario": {"schema": "regrasp.scenario/1", "name": "console-e2e"},
        "object": {"name": "box", "mass_kg": 8.0, "com_local": [0.0, 0.0, 0.0],
                   "start_pose": [0.5, -0.2, 0.8, 0, 0, 0, 1], "goal_pose": [0.5, 0.2, 0.8, 0, 0, 0, 1]},
        "support_polygon": POLYGON, "threshold_m": THRESHOLD_M, "hands": "right-right", "dt_s": dt,
        "trajectory": traj,
        "segments": [{"kind": "approach", "hand": "right", "first": 0, "last": 119},
                     {"kind": "transfer", "hand": "right", "first": 120, "last": 319},
                     {"kind": "retreat", "hand": "right", "first": 320, "last": n - 1}],
        "min_margin_m": min(p["margin_m"] for p in traj), "alternatives": [], "stats": {},
    }


def synthetic_survey() -> dict[str, Any]:
    return {
        "schema": "regrasp.survey/2", "robot": {"name": "hrp5p", "urdf_sha256": "0" * 64},
        "stance": {"name": "upright"}, "threshold_m": THRESHOLD_M, "seed": 1, "object": {},
        "estimator": {"until": "solved", "ci_half_width": 0.02, "seeds_min": 10, "seeds_max": 256},
        "rows": [
            {"hands": "left-left", "stable": 10529, "unstable": 15, "ratio": 0.9986, "ratio_ci95": [0.9961, 1.0],
             "seeds": 12, "converged": True},
            {"hands": "right-right", "stable": 9920, "unstable": 80, "ratio": 0.992, "ratio_ci95": [0.984, 0.998],
             "seeds": 12, "converged": True},
            {"hands": "left-right", "stable": 6100, "unstable": 3900, "ratio": 0.61, "ratio_ci95": [0.58, 0.64],
             "seeds": 30, "converged": True},
            {"hands": "right-left", "stable": 0, "unstable": 0, "ratio": None, "reason": "no feasible handover"},
        ],
        "recommended": "left-left", "indistinguishable": ["right-right"], "stats": {},
    }


class FakeJobs:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.jobs: dict[str, dict[str, Any]] = {}
        self.events: list[dict[str, Any]] = []
        #: False makes the events route answer 404, as a server without SSE would.
        self.sse_enabled = True
        #: False makes GET /v1/me answer 404 (the console then shows buttons by job state only).
        self.me_enabled = True
        #: Length of one of the EXECUTION_STEPS of a dispatched job, s (a test of stop makes it longer).
        self.execution_step_s = EXECUTION_STEP_S
        #: Running executions: job id -> (thread, stop event); a stop wakes the thread at once.
        self.executions: dict[str, tuple[threading.Thread, threading.Event]] = {}
        #: Rejections received: job id, by whom, the reason given.
        self.rejections: list[dict[str, str]] = []
        plan = self.add("plan", "alice", state="planned")
        self._new("survey", "alice", state="succeeded", result=synthetic_survey(), progress=1.0)
        self.plan_id = plan["id"]

    def _new(self, kind: str, submitter: str, *, state: str, result: dict | None = None, progress: float = 0.0) -> dict:
        job = {"id": str(uuid.uuid4()), "kind": kind, "state": state, "progress": progress, "message": None,
               "submitter": submitter, "request": {"scenario": "upright"}, "result": result, "error": None,
               "plan_sha256": None, "approval": None, "cancel_requested": False, "attempts": 1,
               "provenance": {"seed": 1}, "audit_head": None, "created_at": _now(), "updated_at": _now(),
               "started_at": None, "finished_at": None}
        self.jobs[job["id"]] = job
        self._event(job, "state")
        return job

    def add(self, kind: str, submitter: str, *, state: str) -> dict:
        """A job in ``state``; a plan from planned on has the synthetic plan (and stays there until acted on)."""
        with self.lock:
            planned = state not in ("queued", "planning")
            job = self._new(kind, submitter, state=state,
                            result=(synthetic_plan() if kind == "plan" else synthetic_survey()) if planned else None)
            if kind == "plan" and planned:
                job["plan_sha256"] = "a" * 64
            return job

    def approve(self, job_id: str, by: str = "bob") -> None:
        """Approve a planned job as ``by`` would (the console's approve button has its own tests)."""
        with self.lock:
            job = self.jobs[job_id]
            job["approval"] = {"approved_by": by, "approved_at": _now(),
                               "expires_at": (datetime.now(timezone.utc) + timedelta(minutes=10)).isoformat(),
                               "plan_sha256": job["plan_sha256"], "comment": None}
            self.set_state(job, "approved", f"approved by {by}")

    def _event(self, job: dict, kind: str, message: str | None = None, data: dict | None = None) -> None:
        self.events.append({"id": len(self.events) + 1, "job_id": job["id"], "at": _now(), "kind": kind,
                            "state": job["state"], "progress": job["progress"], "message": message, "data": data or {}})

    def set_state(self, job: dict, state: str, message: str | None = None) -> None:
        job["state"] = state
        job["message"] = message
        job["updated_at"] = _now()
        job["audit_head"] = uuid.uuid4().hex * 2
        self._event(job, "state", message)

    def plan_later(self, job_id: str) -> None:
        """A submitted job plans in the background: planning, then planned (or succeeded for a survey)."""
        def run() -> None:
            time.sleep(EXECUTION_STEP_S)
            with self.lock:
                job = self.jobs[job_id]
                if job["state"] != "queued":  # canceled before a worker took it
                    return
                self.set_state(job, "planning", "a worker started planning")
            time.sleep(EXECUTION_STEP_S)
            with self.lock:
                job = self.jobs[job_id]
                if job["state"] != "planning":
                    return
                job["progress"] = 1.0
                if job["kind"] == "plan":
                    job["result"], job["plan_sha256"] = synthetic_plan(), "b" * 64
                    self.set_state(job, "planned", "planned; waiting for approval")
                else:
                    job["result"] = synthetic_survey()
                    self.set_state(job, "succeeded", "survey done")
        threading.Thread(target=run, daemon=True).start()

    def execute(self, job_id: str) -> None:
        """Play a short execution in a thread: executing with progress, then succeeded."""
        step_s = self.execution_step_s
        stop = threading.Event()

        def run() -> None:
            if stop.wait(step_s):
                return
            with self.lock:
                job = self.jobs[job_id]
                if job["state"] != "dispatching":  # stopped before it started
                    return
                self.set_state(job, "executing", "segment 1 started")
            for step in range(1, EXECUTION_STEPS + 1):
                if stop.wait(step_s):
                    return
                with self.lock:
                    job = self.jobs[job_id]
                    if job["state"] != "executing":
                        return
                    # As the real bridge: the index the controller reports, as a bridge event.
                    index = round(step / EXECUTION_STEPS * (len(job["result"]["trajectory"]) - 1))
                    self._event(job, "bridge", "executing", {"event": "executing", "payload": {"index": index}})
            with self.lock:
                self.set_state(self.jobs[job_id], "succeeded", "execution finished")
        thread = threading.Thread(target=run, daemon=True)
        self.executions[job_id] = (thread, stop)
        thread.start()


def problem(status: int, detail: str) -> JSONResponse:
    titles = {401: "Unauthorized", 403: "Forbidden", 404: "Not Found", 409: "Conflict", 422: "Unprocessable Entity"}
    return JSONResponse({"type": "about:blank", "title": titles.get(status, "Error"), "status": status,
                         "detail": detail}, status_code=status, media_type="application/problem+json")


def create_app(check: ContractCheck | None = None) -> FastAPI:
    """The fake; with ``check``, every exchange is validated against the real API's OpenAPI document."""
    app = FastAPI()
    store = FakeJobs()
    app.state.store = store
    if check is not None:
        install(app, check)

    def who(request: Request) -> tuple[str, set[str]] | JSONResponse:
        auth = request.headers.get("authorization", "")
        if not auth.lower().startswith("bearer "):
            return problem(401, "no bearer token: send 'Authorization: Bearer TOKEN'")
        found = TOKENS.get(auth[7:].strip())
        return found if found is not None else problem(401, "unknown bearer token")

    def view(job: dict, with_result: bool = True) -> dict:
        return job if with_result else {**job, "result": None}

    @app.get("/")
    def index() -> FileResponse:
        return FileResponse(CONSOLE_DIR / "index.html", media_type="text/html")

    app.mount("/console", StaticFiles(directory=CONSOLE_DIR, html=True), name="console")

    @app.get("/healthz")
    def healthz() -> dict:
        return {"status": "ok", "database": "memory", "executor": "fake", "workers": 0, "queue_depth": 0,
                "controller_alive": True, "version": "fake"}

    @app.get("/v1/me")
    def me(request: Request) -> Any:
        if not store.me_enabled:
            return JSONResponse({"detail": "Not Found"}, status_code=404,
                                headers={DEVIATION_HEADER: "a service without /v1/me"})
        p = who(request)
        if isinstance(p, JSONResponse):
            return p
        return {"user": p[0], "roles": sorted(p[1])}

    @app.get("/v1/jobs")
    def list_jobs(request: Request) -> Any:
        p = who(request)
        if isinstance(p, JSONResponse):
            return p
        with store.lock:
            jobs = sorted(store.jobs.values(), key=lambda j: j["created_at"], reverse=True)
            return {"jobs": [view(j, False) for j in jobs], "total": len(jobs), "limit": 100, "offset": 0}

    @app.post("/v1/jobs", status_code=202)
    async def submit(request: Request) -> Any:
        p = who(request)
        if isinstance(p, JSONResponse):
            return p
        if not ({"planner", "admin"} & p[1]):
            return problem(403, f"submitting a job needs the role 'planner'; user {p[0]!r} has {sorted(p[1])}")
        body = await request.json()
        with store.lock:
            job = store._new(body["kind"], p[0], state="queued")
            job["request"] = body.get("request", {})
        store.plan_later(job["id"])
        return JSONResponse(job, status_code=202, headers={"Location": f"/v1/jobs/{job['id']}"})

    @app.get("/v1/jobs/{job_id}")
    def get_job(job_id: str, request: Request) -> Any:
        p = who(request)
        if isinstance(p, JSONResponse):
            return p
        with store.lock:
            job = store.jobs.get(job_id)
            return dict(job) if job else problem(404, f"no job {job_id}")

    @app.get("/v1/catalogue")
    def catalogue(request: Request) -> Any:
        p = who(request)
        if isinstance(p, JSONResponse):
            return p
        scenario = {"robot": "hrp5p", "hands": "auto", "seed": 1, "time_limit_s": 60.0, "object_shape": "box",
                    "object_mass_kg": 8.0}
        return {"kinds": ["plan", "survey"], "meshes": [], "stances": ["upright", "staggered", "crouched", "one-legged"],
                "hands": ["auto", "left-left", "right-right", "left-right", "right-left"], "robots": ["hrp5p", "jvrc1"],
                "scenarios": [{**scenario, "name": "upright", "stance": "upright", "threshold_m": 0.06},
                              {**scenario, "name": "staggered", "stance": "staggered", "threshold_m": 0.03}]}

    @app.get("/v1/jobs/{job_id}/risk")
    def risk(job_id: str, request: Request) -> Any:
        p = who(request)
        if isinstance(p, JSONResponse):
            return p
        with store.lock:
            job = store.jobs.get(job_id)
            if job is None or job["result"] is None:
                return problem(404, f"no plan for job {job_id}")
            traj = job["result"]["trajectory"]
            worst = min(range(len(traj)), key=lambda i: traj[i]["margin_m"])
        moment = {"sample": worst * 2, "point": worst, "t": traj[worst]["t"], "segment": None}
        return {"job_id": job_id, "unconstrained": None, "dispatch": None,
                "planning": {"schema": "regrasp.risk/1", "plan_sha256": job["plan_sha256"], "threshold_m": THRESHOLD_M,
                             "gate": {"passed": True, "check": None, "message": "every check passed", "failed_at": None,
                                      "samples": 2 * len(traj), "checks_passed": ["structure"], "skipped": []},
                             "com_margin": {"min_margin_m": traj[worst]["margin_m"],
                                            "headroom_m": traj[worst]["margin_m"] - THRESHOLD_M, "hand": "none", **moment},
                             "zmp": None, "effort": None}}

    @app.get("/v1/jobs/{job_id}/audit")
    def audit(job_id: str, request: Request) -> Any:
        p = who(request)
        if isinstance(p, JSONResponse):
            return p
        return Response(b"\x89MCAP0\r\n", media_type="application/octet-stream")

    @app.get("/v1/jobs/{job_id}/events")
    async def events(job_id: str, request: Request) -> Any:
        p = who(request)
        if isinstance(p, JSONResponse):
            return p
        if not store.sse_enabled:
            return problem(404, "no event stream here")
        after = int(request.headers.get("last-event-id") or 0)

        async def stream():
            cursor = after
            yield "retry: 1000\n\n"
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline:
                with store.lock:
                    new = [e for e in store.events if e["job_id"] == job_id and e["id"] > cursor]
                done = False
                for event in new:
                    cursor = event["id"]
                    yield f"id: {event['id']}\nevent: {event['kind']}\ndata: {json.dumps(event)}\n\n"
                    if event["kind"] == "state" and event["state"] in TERMINAL:
                        done = True
                if done or await request.is_disconnected():
                    return
                await asyncio.sleep(0.05)

        return StreamingResponse(stream(), media_type="text/event-stream")

    def action(job_id: str, request: Request, role: str | None, allowed: set[str]) -> tuple[dict, tuple] | JSONResponse:
        p = who(request)
        if isinstance(p, JSONResponse):
            return p
        if role is not None and not ({role, "admin"} & p[1]):
            return problem(403, f"this action needs the role {role!r}; user {p[0]!r} has {sorted(p[1])}")
        job = store.jobs.get(job_id)
        if job is None:
            return problem(404, f"no job {job_id}")
        if job["state"] not in allowed:
            return problem(409, f"job {job_id} is {job['state']}")
        return job, p

    @app.post("/v1/jobs/{job_id}/approve")
    async def approve(job_id: str, request: Request) -> Any:
        # The body is read before the lock: awaiting it while holding a threading lock would let the event loop
        # run the event stream, whose `with store.lock` would then block the loop's one thread for good.
        body = await request.json() if await request.body() else {}
        with store.lock:
            found = action(job_id, request, "approver", {"planned"})
            if isinstance(found, JSONResponse):
                return found
            job, p = found
            if job["submitter"] == p[0]:
                return problem(403, f"two-person rule: {p[0]} submitted job {job_id} and cannot approve it")
            if body.get("plan_sha256") not in (None, job["plan_sha256"]):
                return problem(409, "the plan changed since you reviewed it")
            job["approval"] = {"approved_by": p[0], "approved_at": _now(),
                               "expires_at": (datetime.now(timezone.utc) + timedelta(minutes=10)).isoformat(),
                               "plan_sha256": job["plan_sha256"], "comment": None}
            store.set_state(job, "approved", f"approved by {p[0]}")
            return dict(job)

    @app.post("/v1/jobs/{job_id}/reject")
    async def reject(job_id: str, request: Request) -> Any:
        body = await request.json() if await request.body() else {}
        with store.lock:
            found = action(job_id, request, "approver", {"planned"})
            if isinstance(found, JSONResponse):
                return found
            reason = str(body.get("reason") or "").strip()
            if not reason:
                return problem(422, 'a rejection needs a reason: send {"reason": "why the plan is declined"}')
            job = found[0]
            job["error"] = {"code": "REJECTED", "message": f"rejected by {found[1][0]}: {reason}"}
            store.rejections.append({"job_id": job_id, "by": found[1][0], "reason": reason})
            store.set_state(job, "rejected", f"rejected by {found[1][0]}: {reason}")
            return dict(job)

    @app.post("/v1/jobs/{job_id}/dispatch")
    def dispatch(job_id: str, request: Request) -> Any:
        with store.lock:
            found = action(job_id, request, "operator", {"approved"})
            if isinstance(found, JSONResponse):
                return found
            store.set_state(found[0], "dispatching", "the gate passed the plan")
            store.execute(job_id)
            return JSONResponse(view(found[0], False), status_code=202)  # the job's summary, no plan body

    @app.post("/v1/jobs/{job_id}/stop")
    def stop(job_id: str, request: Request) -> Any:
        with store.lock:
            found = action(job_id, request, "operator", {"dispatching", "executing"})
            if isinstance(found, JSONResponse):
                return found
            store.set_state(found[0], "aborted", f"stopped by {found[1][0]}")
            execution = store.executions.get(job_id)
            if execution is not None:
                execution[1].set()
            return JSONResponse(dict(found[0]), status_code=202)

    @app.post("/v1/jobs/{job_id}/cancel")
    def cancel(job_id: str, request: Request) -> Any:
        with store.lock:
            found = action(job_id, request, None, {"queued", "planning", "planned", "approved"})
            if isinstance(found, JSONResponse):
                return found
            job, p = found
            if job["submitter"] != p[0] and "admin" not in p[1]:
                return problem(403, f"only the submitter ({job['submitter']}) or an admin can cancel job {job_id}")
            store.set_state(job, "canceled", f"canceled by {p[0]}")
            return JSONResponse(dict(job), status_code=202)

    return app
