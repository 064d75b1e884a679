"""The end-to-end demo: the paper's scenario through the real service, gate and simulated robot.

With another robot than the HRP-5P model the demo runs that robot's own version of the paper's upright
task (a built-in ``ROBOT-upright`` scenario, such as ``talos-upright``), else the upright task with the
robot swapped in.

Every component runs for real on loopback: a simulated controller peer (zenoh), the HTTP
service with its worker processes and SQLite job store, the safety gate and the MCAP audit.
The demo users are the personas of ``regrasp serve --dev`` (service.api.auth.DEV_USERS): alice plans,
carol approves, bob operates the robot (he may also approve). Each step is printed as it runs,
including the planning progress and the execution's progress as the controller reports it.
Every file is written once: the audit file stays where the service wrote it.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal

from pydantic import BaseModel, Field

from schemas.survey import recommendation_text

#: Longest the demo stays silent, s (then it says what it is still waiting for).
QUIET_S = 2.5


class DemoSettings(BaseModel):
    """What the demo runs and how long it waits (SI units)."""

    scenario: str = "upright"
    robot: str | None = Field(None, description="registered robot the scenario runs with, over its own robot (None: "
                              "the scenario's); the controller simulator plays that robot")
    survey_states: int | None = Field(None, ge=1, description="None: the scenario's own estimator (seeds until the "
                                      "intervals are tight), the answer `regrasp survey` and `hands: auto` give; N: N "
                                      "states per seed over 10 seeds instead, a quicker look")
    controller_speed: float = Field(1.0, gt=0, description="the simulated controller plays K times faster than real time "
                                                         "(the physics twin: simulated time K times the wall clock)")
    plant: Literal["kinematic", "physics"] = Field("physics", description="the simulated controller's plant: the MuJoCo "
                                                                          "twin (measured joints, balance, faults) or a "
                                                                          "replay of the commands")
    workers: int = Field(2, ge=1)
    watchdog_timeout_s: float = Field(3.0, gt=0, le=5.0, description="bridge watchdog for the simulated controller "
                                      "(the robot default is 0.25 s): the demo shares a laptop or a VM with everything "
                                      "else, whose pauses of a second would abort it; a lost controller process still "
                                      "aborts at once, its liveliness token goes with its socket")
    lease_s: float = Field(3.0, gt=0, le=60, description="zenoh transport lease of the demo's peers (the robot default "
                                                          "is 1 s): a pause of the machine longer than the lease drops "
                                                          "the controller's liveliness token and aborts the execution")
    figure_format: Literal["png", "svg", "pdf"] = Field("png", description="format of the demo's figures")
    start_timeout_s: float = Field(60.0, gt=0)
    job_timeout_s: float = Field(300.0, gt=0)


@dataclass
class DemoResult:
    ok: bool
    steps: list[tuple[str, str]] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)
    artefacts: dict[str, str] = field(default_factory=dict)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for(predicate: Callable[[], bool], timeout: float, what: str, proc: subprocess.Popen | None = None) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"{what}: the process exited with code {proc.returncode}")
        try:
            if predicate():
                return
        except Exception:  # noqa: BLE001 - not up yet
            pass
        time.sleep(0.1)
    raise TimeoutError(f"{what} did not come up within {timeout:.0f} s")


def _start(cmd: list[str], env: dict[str, str], log: Path) -> subprocess.Popen:
    handle = open(log, "w")
    return subprocess.Popen(cmd, env=env, stdout=handle, stderr=subprocess.STDOUT, start_new_session=True)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=10)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


class Narrator:
    """The demo's voice: says each line, and says what is still going on when nothing was said for a while,
    so that a person watching never waits in silence (a survey's seeds can run for many seconds)."""

    def __init__(self, say: Callable[[str], None], quiet_s: float = QUIET_S) -> None:
        self._say, self.quiet_s = say, quiet_s
        self._lock = threading.Lock()
        self._last = time.monotonic()
        self._activity: tuple[str, float] | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="demo-narrator", daemon=True)
        self._thread.start()

    def __call__(self, text: str) -> None:
        with self._lock:
            self._say(text)
            self._last = time.monotonic()

    def doing(self, what: str | None) -> None:
        """What the demo waits for now (None: nothing worth a reminder)."""
        with self._lock:
            self._activity = None if what is None else (what, time.monotonic())

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)

    def _watch(self) -> None:
        while not self._stop.wait(0.25):
            with self._lock:
                now = time.monotonic()
                if self._activity is None or now - self._last < self.quiet_s:
                    continue
                what, since = self._activity
                self._say(f"  ... {what} ({now - since:.0f} s so far)")
                self._last = now


def run_demo(out: Path, settings: DemoSettings, say: Callable[[str], None]) -> DemoResult:
    """The demo, narrated: never more than ``QUIET_S`` without a line."""
    narrator = Narrator(say)
    try:
        return _run_demo(out, settings, narrator)
    finally:
        narrator.close()


def _run_demo(out: Path, settings: DemoSettings, say: Narrator) -> DemoResult:
    from service.client import ServiceClient, ServiceError

    out.mkdir(parents=True, exist_ok=True)
    data_dir = out / "service-data"
    if data_dir.exists():
        shutil.rmtree(data_dir)
    result = DemoResult(ok=False)
    from service.api.auth import DEV_USERS, make_dev_tokens

    tokens = make_dev_tokens()  # the same users and roles as `regrasp serve --dev`
    tok = {v["user"]: k for k, v in tokens.items()}
    roles = {user: ", ".join(r) for user, r in DEV_USERS.items()}
    http_port, zenoh_port = free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{zenoh_port}"
    # A key pair for this run: the service signs every command with it, the controller trusts its public half.
    from robot_bridge.signing import generate_keys

    signing_key, trusted_key = generate_keys(data_dir / "keys")
    robot = settings.robot or _robot_of(settings.scenario)
    env = dict(os.environ, REGRASP_TOKENS=json.dumps(tokens), REGRASP_BRIDGE_CONNECT=json.dumps([endpoint]),
               REGRASP_BRIDGE_ROBOT_ID=robot,  # the service talks to the controller of the robot the plan is for
               REGRASP_BRIDGE_SIGNING_KEY=str(signing_key), REGRASP_BRIDGE_TRUSTED_KEY=str(trusted_key),
               REGRASP_DISPATCH_LOOKAHEAD_SEGMENTS=str(_lookahead_segments(settings.controller_speed)),
               # The simulated controller shares the machine's cores with planning workers; on a loaded
               # host a 0.25 s heartbeat gap is the scheduler, not a dead controller. A robot keeps 0.25 s.
               REGRASP_BRIDGE_WATCHDOG_TIMEOUT_S=str(settings.watchdog_timeout_s),
               REGRASP_BRIDGE_LEASE_S=str(settings.lease_s),
               # only plans whose physics dry run stood are dispatched (the risk card's, checked by the service)
               REGRASP_REQUIRE_PHYSICS_PASS="true",
               PYTHONUNBUFFERED="1")
    exe = [sys.executable, "-m", "service.cli.main"]
    with ExitStack() as stack:
        say(f"starting the simulated controller of {robot} (zenoh {endpoint}, {settings.controller_speed:g}x real time)")
        sim = _start([*exe, "controller-sim", "--robot", robot, "--stance", _stance_of(settings.scenario),
                      "--speed", str(settings.controller_speed), "--plant", settings.plant, "--listen", endpoint], env,
                     out / "controller-sim.log")
        stack.callback(_stop, sim)
        say(f"starting the service on http://127.0.0.1:{http_port} ({settings.workers} workers, SQLite in {data_dir})")
        say.doing("the service is starting (loading the robot model)")
        srv = _start([*exe, "serve", "--host", "127.0.0.1", "--port", str(http_port), "--data-dir", str(data_dir),
                      "--workers", str(settings.workers)], env, out / "service.log")
        stack.callback(_stop, srv)
        base = f"http://127.0.0.1:{http_port}"
        alice = stack.enter_context(ServiceClient(base, tok["alice"]))
        bob = stack.enter_context(ServiceClient(base, tok["bob"]))
        carol = stack.enter_context(ServiceClient(base, tok["carol"]))
        _wait_for(lambda: alice.health() is not None, settings.start_timeout_s, "the service", srv)
        result.steps.append(("service", "up"))
        say(f"users (as `regrasp serve --dev`): alice ({roles['alice']}), carol ({roles['carol']}), bob ({roles['bob']})")

        budget = ({} if settings.survey_states is None else
                  {"until": "states", "states_per_seed": settings.survey_states, "seeds_min": 10, "seeds_max": 10})
        if settings.robot is not None:
            budget["robot"] = settings.robot
        say(f"alice submits the stability survey of scenario {settings.scenario!r} with {robot} "
            f"({'the scenario estimator' if settings.survey_states is None else str(settings.survey_states) + ' states per seed'})")
        job = alice.submit("survey", {"scenario": settings.scenario, **budget})
        say.doing("the survey is exploring each hand configuration, seed after seed")
        survey_job = alice.wait(job["id"], timeout=settings.job_timeout_s, on_event=ProgressReporter(say, "survey"))
        if survey_job["state"] != "succeeded":
            raise RuntimeError(f"survey job ended {survey_job['state']}: {survey_job.get('error')}")
        survey = survey_job["result"]
        (out / "survey.json").write_text(json.dumps(survey, indent=1))
        result.artefacts["survey"] = str(out / "survey.json")
        hands = survey["recommended"]
        result.summary["robot"] = survey["robot"]["name"]
        result.summary["survey"] = {r["hands"]: r["ratio"] for r in survey["rows"]}
        result.summary["recommended"] = hands
        # The interval, the seeds and the ties, as the survey gives them (one recommendation per task).
        result.summary["survey_intervals"] = {r["hands"]: {"ratio": r["ratio"], "ratio_ci95": r.get("ratio_ci95"),
                                                           "seeds": r.get("seeds")} for r in survey["rows"]}
        result.summary["survey_ties"] = list(survey.get("indistinguishable") or [])
        result.steps.append(("survey", f"recommended {recommendation_text(survey)}"))

        say(f"alice submits the plan with hands: auto (the survey's answer, {hands}, from the service's survey cache)")
        job = alice.submit("plan", {"scenario": settings.scenario, "hands": "auto", **budget})
        say.doing("the planner is searching for a regrasp motion that keeps the CoM margin")
        plan_job = alice.wait(job["id"], states=("planned", "failed", "canceled"), timeout=settings.job_timeout_s,
                              on_event=ProgressReporter(say, "plan"))
        if plan_job["state"] != "planned":
            raise RuntimeError(f"plan job ended {plan_job['state']}: {plan_job.get('error')}")
        plan = plan_job["result"]
        (out / "plan.json").write_text(json.dumps(plan))
        result.artefacts["plan"] = str(out / "plan.json")
        result.summary.update(min_margin_m=plan["min_margin_m"], threshold_m=plan["threshold_m"],
                              planning_time_s=plan["stats"].get("time_s"), duration_s=plan["trajectory"][-1]["t"],
                              hands=plan["hands"], max_effort_ratio=max(p.get("effort_ratio") or 0.0 for p in plan["trajectory"]))
        result.steps.append(("plan", f"{plan['hands']}, min margin {plan['min_margin_m'] * 1000:.1f} mm"))
        say.doing("the physics twin is dry-running the plan for the risk card")
        result.summary["physics"] = _physics_line(alice, plan_job["id"])
        say(f"the risk card's physics dry run: {result.summary['physics']}")

        say("alice tries to approve her own plan (refused: a planner is not an approver, and never of her own plan)")
        try:
            alice.approve(plan_job["id"])
            raise RuntimeError("the submitter was allowed to approve her own plan")
        except ServiceError as exc:
            if exc.status != 403:
                raise RuntimeError(f"alice's self-approval was refused for another reason: {exc}") from None
            result.steps.append(("two-person rule", f"alice refused ({exc.status})"))
        say(f"carol approves the plan (bound to its SHA-256 {plan_job['plan_sha256'][:12]}...)")
        say.doing("the approval is being recorded")
        carol.approve(plan_job["id"], plan_sha256=plan_job["plan_sha256"])
        result.steps.append(("approval", "carol approved"))

        say("bob dispatches: the safety gate rechecks every 5 ms sample, then the segments stream to the controller")
        _wait_for(lambda: bob.health().get("controller_alive", True), settings.start_timeout_s, "the simulated controller", sim)
        say.doing("the safety gate is checking the plan before the robot moves")
        bob.dispatch(plan_job["id"])
        from schemas.jobs import TERMINAL_STATES

        say.doing("the robot is moving")
        done = bob.wait(plan_job["id"], states=TERMINAL_STATES, timeout=settings.job_timeout_s,
                        on_event=ProgressReporter(say, "execution", points=len(plan["trajectory"])))
        outcome = done["state"] if done["state"] == "succeeded" else f"{done['state']}: {(done.get('error') or {}).get('message')}"
        result.summary["execution"] = outcome
        result.steps.append(("execution", outcome))
        say("waiting for the audit file to be sealed")
        say.doing("the audit file is being sealed")
        audit_path, verdict = _sealed_audit(data_dir / "audit", plan_job["id"], settings.job_timeout_s)
        result.artefacts["audit"] = str(audit_path)
        result.summary["audit"] = f"{verdict.status}, {verdict.records} chained records"
        result.summary["audit_exit_code"] = verdict.exit_code
        result.ok = done["state"] == "succeeded" and verdict.exit_code == 0
    say("drawing the plots")
    say.doing("the plots are being drawn")
    _plots(out, plan, survey, result, settings.figure_format)
    say.doing(None)
    return result


class ProgressReporter:
    """Prints a job's progress from its events as they come: planning messages, the gate, execution progress.

    Planning messages are printed when they change, at most every ``min_interval_s``; execution
    progress at every tenth of the plan's points the controller reports.
    """

    def __init__(self, say: Callable[[str], None], what: str, *, points: int | None = None,
                 min_interval_s: float = 2.0) -> None:
        self.say, self.what, self.points, self.min_interval_s = say, what, points, min_interval_s
        #: An execution's reporter skips the planning history the event stream replays first.
        self.planning = points is None
        self.last_message: str | None = None
        self.last_at = -math.inf
        self.next_tenth = 1

    def __call__(self, event: dict[str, Any]) -> None:
        kind, data = event.get("kind"), event.get("data") or {}
        if kind == "bridge":
            self._bridge(str(data.get("event")), data.get("payload") or {})
        elif kind == "progress" and event.get("message") and self.planning:
            now = time.monotonic()
            if event["message"] != self.last_message and now - self.last_at >= self.min_interval_s:
                self.last_message, self.last_at = event["message"], now
                self.say(f"  {self.what}: {event['message']} ({100 * (event.get('progress') or 0):.0f} %)")

    def _bridge(self, name: str, d: dict[str, Any]) -> None:
        if name == "gate":
            self.say("  safety gate: " + (f"passed ({d.get('samples')} samples)" if d.get("passed")
                                          else f"veto [{d.get('check')}]: {d.get('message')}"))
        elif name == "dispatching":
            self.points = d.get("points") or self.points
            self.say(f"  sending {d.get('segments')} segments ({self.points} points) to the controller")
        elif name in ("executing", "robot_state") and self.points and isinstance(d.get("index"), int):
            while self.next_tenth <= 10 and d["index"] >= self.next_tenth * (self.points - 1) / 10:
                self.say(f"  executing: {10 * self.next_tenth} % (point {d['index']} of {self.points - 1})")
                self.next_tenth += 1
        elif name == "finished":
            self.say(f"  execution finished: {d.get('status')}" + (f" ({d['reason']})" if d.get("reason") else ""))
        elif name in ("controller", "stop_sent"):
            self.say(f"  controller: {d.get('status') or 'stop sent'}" + (f" ({d['reason']})" if d.get("reason") else ""))


def _sealed_audit(audit_dir: Path, job_id: str, timeout: float):
    """The service's own audit file of the job, once its writer has sealed it (it trails the job by a moment)."""
    from service.audit.verify import verify

    path = audit_dir / f"{job_id}.mcap"
    deadline = time.monotonic() + timeout
    verdict = None
    while time.monotonic() < deadline:
        try:
            if path.is_file():
                verdict = verify(path)
                if verdict.finished:
                    return path, verdict
        except (OSError, ValueError):
            pass
        time.sleep(0.5)
    if verdict is None:
        raise TimeoutError(f"the audit file of job {job_id} was not written within {timeout:.0f} s")
    return path, verdict


def _physics_line(client: Any, job_id: str) -> str:
    """The risk card's physics dry run in one line (the twin's verdict before anyone approves)."""
    try:
        card = (client.risk(job_id) or {}).get("planning") or {}
    except Exception as exc:  # noqa: BLE001 - the line is information; dispatch still checks the policy
        return f"not available ({exc})"
    phys = card.get("physics") or {}
    if "report" not in phys:
        return phys.get("error", "not run")
    rep, at = phys["report"], phys.get("at") or {}
    seg = at.get("segment") or {}
    where = f"at {at['t']:.2f} s ({seg.get('kind', '?')}, {seg.get('hand', '?')} hand)" if at.get("t") is not None else ""
    if rep.get("fault"):
        return f"{'fell' if rep['fell'] else 'faulted'}: {rep['fault']['kind']} {where}"
    return (f"stood; min CoP margin {rep['min_cop_margin_m'] * 1000:.1f} mm {where}, "
            f"{rep['cop_margin_ratio']:.2f} of the plan's CoM margin")


def _lookahead_segments(speed: float) -> int:
    """Segments the dispatcher keeps ahead so that a controller playing ``speed`` x real time
    still has as much wall time buffered as the default gives a real-time one."""
    from robot_bridge.dispatcher import DispatchSettings

    default = DispatchSettings.model_fields["lookahead_segments"].default
    return max(default, math.ceil(default * speed))


def _robot_of(scenario: str) -> str:
    from planner.api.catalogue import load_scenario

    return load_scenario(scenario).robot


def default_scenario(robot: str) -> str:
    """The demo's scenario for a robot: the paper's upright task, as the built-in scenario made for that robot
    (``ROBOT-upright``) where there is one."""
    from planner.api.catalogue import builtin_names, load_builtin

    own = f"{robot}-upright"
    if own in builtin_names() and load_builtin(own).robot == robot:
        return own
    return "upright"


def _stance_of(scenario: str) -> str:
    from planner.api.catalogue import load_scenario

    st = load_scenario(scenario).stance
    return st if isinstance(st, str) else st.name


def _plots(out: Path, plan: dict, survey: dict, result: DemoResult, fmt: str = "png") -> None:
    import numpy as np

    from experiments.plots import (
        describe,
        holding_events,
        plot_com_trace,
        plot_margin_over_time,
        plot_survey_bars,
    )

    scenario, stance = plan["scenario"]["name"], plan["stance"]["name"]
    poly = np.array(plan["support_polygon"])
    xy = np.array([p["com"][:2] for p in plan["trajectory"]])
    head = describe(scenario, stance, plan["threshold_m"], hands=plan["hands"])
    result.artefacts["com_trace"] = str(plot_com_trace(out / f"plan-com-trace.{fmt}", title=f"CoM ground trace\n{head}",
                                                       polygon=poly, threshold_m=plan["threshold_m"],
                                                       traces=[(f"CoM, {plan['threshold_m'] * 1000:g} mm plan", xy, "tab:blue")]))
    t = np.array([p["t"] for p in plan["trajectory"]])
    m = np.array([p["margin_m"] for p in plan["trajectory"]])
    result.artefacts["margin"] = str(plot_margin_over_time(out / f"plan-margin.{fmt}", title=f"CoM margin over time\n{head}",
                                                           threshold_m=plan["threshold_m"], traces=[("planned margin", t, m, "tab:blue")],
                                                           events=holding_events(plan["trajectory"])))
    stats = survey.get("stats") or {}
    states = stats.get("states_per_configuration")
    title = "stable ratio R per hand configuration\n" + describe(scenario, survey["stance"]["name"], survey["threshold_m"],
                                                                 states=states) + (" per configuration" if states else "")
    result.artefacts["survey_chart"] = str(plot_survey_bars(out / f"survey-bars.{fmt}", title=title, rows=survey["rows"],
                                                            recommended=survey.get("recommended"),
                                                            indistinguishable=survey.get("indistinguishable") or ()))
