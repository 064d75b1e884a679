"""Plan and survey jobs: a scenario (plus overrides) in, a contract document out.

Used by ``regrasp plan``/``regrasp survey`` and by the service's workers (through
:mod:`planner.jobs.entry`). Bad input that prevents planning raises :class:`planner.errors.InputError`
(a usage error); planning that runs and finds nothing returns ``status: infeasible``
with a failure code and the failures counted by cause.
"""

from __future__ import annotations

import importlib.metadata as md
import platform
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable

from planner.blas_threads import one_blas_thread
from planner.errors import Canceled, InputError
from planner.jobs.robot_task import scenario_for_robot
from planner.jobs.survey_job import survey_overrides
from planner.regrasp.failure_cause import FailureCause, failures_in_words
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.plan_assembly import assemble, effort_ratios, trajectory_points
from planner.regrasp.timing.plan_timer import PlanTimer
from planner.regrasp.timing.settings import PlanTimingSettings
from planner.stability.effort import EffortEvaluator
from planner.regrasp.results import PlannerResult
from planner.regrasp.settings import PlannerSettings
from planner.regrasp.search_data import SearchData
from planner.regrasp.task import Task
from planner.scene.meshes import portable_dump
from planner.scene.objects import ObjectModelError
from planner.scene.placements import PlacementError
from planner.scene.scenarios import resolve_scenario, with_overrides
from planner.stability.stances import StanceError
from planner.survey.auto import auto_order, survey_summary
from planner.termination import Termination, never
from schemas.plan import PLAN_SCHEMA
from schemas.policy import default_policy
from schemas.scenario import Scenario

ProgressFn = Callable[[float, str], None]
StopFn = Callable[[], bool]


@dataclass
class PlanOptions:
    hands: str | None = None
    threshold_m: float | None = None
    seed: int | None = None
    solutions: int = 1
    stance: Any = None
    time_limit_s: float | None = None
    #: check effort and grip (CONTRACT section 3); False is ``--no-limits``
    limits: bool = True
    #: a registered robot name or a spec file path, over the scenario's ``robot``
    robot: str | None = None
    #: the object's mass (kg), over the scenario's (and over a fitted task's)
    mass_kg: float | None = None
    #: share of the time-optimal speed (0 < S <= 1), over the scenario's ``speed_scale``
    speed_scale: float | None = None


def library_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist in ("hrp-regrasp", "numpy", "pin", "python-fcl", "trimesh", "networkx", "scipy", "pydantic"):
        try:
            out[dist] = md.version(dist)
        except md.PackageNotFoundError:
            pass
    return out


def _infeasible(task_or_none: Task | None, scenario: Scenario, code: str, message: str, counts: dict | None = None,
                hands: str | None = None, stats: dict | None = None) -> dict[str, Any]:
    from planner.robot.model import load_robot
    from planner.stability.stances import solve_stance

    robot = task_or_none.robot if task_or_none else load_robot(scenario.robot)
    try:
        stance = task_or_none.stance if task_or_none else solve_stance(robot, scenario.stance)
        stance_doc = stance.result().model_dump()
        polygon = stance.polygon.vertices.tolist()
    except (StanceError, ValueError):
        stance_doc = {"name": str(scenario.stance if isinstance(scenario.stance, str) else scenario.stance.name),
                      "base_pose": [0, 0, 0, 0, 0, 0, 1.0], "feet": []}
        polygon = []
    return {
        "schema": PLAN_SCHEMA,
        "status": "infeasible",
        "failure": {"code": code, "message": message, "counts": dict(counts or {})},
        "robot": {"name": robot.name, "urdf_sha256": robot.urdf_sha256, "joint_names": list(robot.joint_names)},
        "scenario": portable_dump(scenario, by_alias=True, mode="json"),
        "stance": stance_doc,
        "support_polygon": polygon,
        "object": {"name": scenario.object.name, "mass_kg": scenario.object.mass_kg,
                   "com_local": list(scenario.object.com_local or [0.0, 0.0, 0.0]),
                   "start_pose": list(scenario.start_pose), "goal_pose": list(scenario.goal_pose)},
        "threshold_m": scenario.threshold_m,
        "hands": hands,
        "dt_s": 0.005,
        "trajectory": [],
        "segments": [],
        "min_margin_m": None,
        "alternatives": [],
        "stats": stats or {},
    }


def timing_zmp_margin(scenario: Scenario, threshold_m: float) -> float:
    """How far inside the polygon the timing keeps the ZMP: the scenario's ``zmp_margin_m``, by default the plan's
    threshold; a user may lower it, never below the safety policy's floor nor raise it above the threshold."""
    asked = scenario.zmp_margin_m
    if asked is None:
        return float(threshold_m)
    floor = default_policy().margin_floor_m
    if asked < floor - 1e-12:
        raise InputError(f"zmp_margin_m {asked * 1000:g} mm is below the safety policy's floor of {floor * 1000:g} mm")
    if asked > threshold_m + 1e-12:
        raise InputError(f"zmp_margin_m {asked * 1000:g} mm is above the plan's threshold of {threshold_m * 1000:g} mm "
                         "(the CoM itself is only held that far inside)")
    return float(asked)


def timing_settings(scenario: Scenario, settings: PlanTimingSettings) -> PlanTimingSettings:
    """The plan timing's settings for this scenario: a user's own ``zmp_margin_m`` is the ZMP's whole margin (no
    reserve share on top of it), so lowering it buys the speed it asks for."""
    return settings if scenario.zmp_margin_m is None else settings.model_copy(update={"zmp_reserve_share": 0.0})


def build_task(scenario: Scenario, settings: PlannerSettings | None = None) -> Task:
    """The task, or an :class:`InputError` whose message names the problem."""
    return Task(scenario, settings)


def _failure_counts(results: list[tuple[PlannerResult, HandConfigPlanner]]) -> dict[str, int]:
    """Removed states by cause, summed over the hand configurations that ran."""
    counts: Counter = Counter()
    for r, _ in results:
        counts.update(r.failures)
    return dict(counts)


def _code_for(res: PlannerResult, planner: HandConfigPlanner) -> tuple[str, str]:
    """The failure code: an end (start or goal) no node could hold says so; else the search's own code."""
    if res.failure_code in ("TIMEOUT", "START_INVALID", "GOAL_INVALID"):  # decided by the planner itself
        return res.failure_code, res.message
    for end, failures, ok, hand in (("start", planner.start_failures, planner.start_ok, planner.start_hand),
                                    ("goal", planner.goal_failures, planner.goal_ok, planner.goal_hand)):
        if failures and not ok:
            dominant = max(failures, key=failures.get)
            limited = {c: failures[c] for c in (FailureCause.EFFORT, FailureCause.GRIP) if failures.get(c)}
            # which joints (or the grip) the limits refuse there, to name them
            over = _end_over_limits(planner, end)
            if limited:  # nodes the limits refused might have held the end: the limits decide (counts in the message)
                dominant = max(limited, key=limited.get)
            elif over is not None:  # the margin refused them first, but the limits refuse them too
                dominant = over[0]
            if over is not None and over[0] == dominant:
                return dominant.upper(), (f"no grasp of the object at its {end} pose with the {hand} hand is valid, and the "
                                          f"robot's limits refuse grasps there: {over[1]} (the validations: "
                                          f"{failures_in_words(failures, 'refused')})")
            if dominant in (FailureCause.EFFORT, FailureCause.GRIP):
                what = ("a joint's static torque over its effort limit" if dominant == FailureCause.EFFORT
                        else "the grip slipping (the object's weight or moment about the jaw's closing axis)")
                return dominant.upper(), (f"no grasp of the object at its {end} pose with the {hand} hand is within the "
                                          f"robot's limits: {what} ({failures_in_words(failures, 'refused')})")
            if dominant == FailureCause.COM_MARGIN:
                return "NO_STABLE_GRASP", (f"no grasp of the object at its {end} pose keeps the CoM margin >= the "
                                           f"threshold with the {hand} hand ({failures_in_words(failures, 'refused')})")
            return f"{end.upper()}_INVALID", (f"the {end} pose cannot be grasped by the {hand} hand: "
                                              f"{failures_in_words(failures, 'refused')}")
    return res.failure_code or "NO_PATH", (res.message
                                           or f"no valid plan; {failures_in_words(res.failures, 'states removed')}")


def _end_over_limits(planner: HandConfigPlanner, end: str) -> tuple[str, str] | None:
    """("effort" or "grip", what was found) when some of the grasps the arm reaches at the end's pose, held
    with the jaw closed, are over the robot's limits, although the validations refused them for another
    cause first (the CoM margin is checked before the limits); None when none is, none is reached, or the
    limits are off."""
    import numpy as np

    from planner.regrasp.graph import PlacementNode
    from planner.regrasp.probes import probe_grasps
    from planner.stability.effort import effort_table

    t = planner.task
    if t.limits is None:
        return None
    pid, hand = (t.start_id, planner.start_hand) if end == "start" else (t.goal_id, planner.goal_hand)
    T_obj = t.placements[pid]
    nodes = [PlacementNode(pid, g, hand) for g, grasp in enumerate(t.grasps[hand]) if planner.cheap_ok(hand, T_obj, grasp)]
    probes = probe_grasps(t, planner.data, nodes)
    reached = [n for n in nodes if probes[n].q is not None]
    if not reached:
        return None
    Q = np.array([probes[n].q for n in reached])
    t.put_jaw(Q, hand, [t.grasps[hand][n.grasp].jaw_value for n in reached])
    res = t.limits.evaluate(Q, hand, object_pose=np.repeat(T_obj[None], len(reached), axis=0))
    effort, grip = ~res.effort_ok, res.effort_ok & ~res.grip_ok
    if not (effort.any() or grip.any()):
        return None
    if effort.sum() >= grip.sum():
        table = effort_table(t.robot)
        worst = np.abs(res.torque[effort]) / table.limit
        joints = sorted({table.checked[k] for k in worst.argmax(axis=1)})
        ratio = res.effort_ratio[effort]
        return FailureCause.EFFORT, (f"{int(effort.sum())} of the {len(reached)} grasps the arm reaches there are over the effort "
                          f"limits, ratio {ratio.min():.2f} to {ratio.max():.2f} ({', '.join(joints)})")
    ratio = res.grip_ratio[grip]
    return FailureCause.GRIP, (f"{int(grip.sum())} of the {len(reached)} grasps the arm reaches there slip, grip ratio "
                    f"{ratio.min():.2f} to {ratio.max():.2f}")


@one_blas_thread
def plan_scenario(
    scenario: Scenario,
    options: PlanOptions | None = None,
    *,
    settings: PlannerSettings | None = None,
    progress: ProgressFn = lambda f, m: None,
    should_stop: StopFn = never,
    task: Task | None = None,
) -> dict[str, Any]:
    """Plan one scenario; returns the plan document (docs/contract.md section 3)."""
    options = options or PlanOptions()
    t_start = time.perf_counter()
    started = time.monotonic()
    scenario = with_overrides(scenario, stance=options.stance, threshold_m=options.threshold_m,
                              hands=options.hands, seed=options.seed, time_limit_s=options.time_limit_s,
                              speed_scale=options.speed_scale)
    progress(0.02, "setting up the task")
    scenario = scenario_for_robot(scenario, options.robot)  # a built-in task run with another robot is fitted to it
    if options.mass_kg is not None:
        scenario = with_overrides(scenario, mass_kg=options.mass_kg)
    if not options.limits:
        settings = (settings or PlannerSettings()).model_copy(update={"limits": False})
    try:
        task = task or build_task(scenario, settings)
    except ObjectModelError as exc:
        raise InputError(f"object: {exc}") from None
    except PlacementError as exc:
        code = "START_INVALID" if exc.end == "start" else "GOAL_INVALID"
        return _infeasible(None, scenario, code, str(exc), stats={"time_s": time.perf_counter() - t_start})
    zmp_margin_m = timing_zmp_margin(scenario, task.threshold_m)
    # What the search learns, shared by the configurations it tries in turn. The survey of `auto` keeps its own:
    # what it learned would steer the search elsewhere, so a plan would differ by whether its survey was cached.
    data = SearchData(task)
    inradius = task.stance.polygon.inradius
    if task.threshold_m > inradius:
        return _infeasible(task, scenario, "THRESHOLD_TOO_LARGE",
                           f"threshold {task.threshold_m * 1000:.1f} mm is larger than the support polygon's inradius "
                           f"{inradius * 1000:.1f} mm in stance {task.stance.name!r}: no state can be stable",
                           stats={"time_s": time.perf_counter() - t_start})
    hands_choice = scenario.hands
    survey_doc = None
    # A user's time limit (none by default) covers everything after the request is read: the survey of
    # `auto`, screening the start and goal, the searches and their motions all stop once it has passed.
    # Without one, the iteration caps alone end the run, so the seed decides the result.
    termination = Termination.of_limits(scenario.limits, should_stop, started=started)

    def timed_out(results: list) -> dict[str, Any]:
        tried = ", ".join(f"{r.hands}: {r.stats.get('search_iterations', 0)} search iterations ({r.status})"
                          for r, _ in results) or "no hand configuration's search had ended"
        return _infeasible(task, scenario, "TIMEOUT", f"no valid plan within {termination.budget_text()}; how far it got: "
                           f"{tried}", _failure_counts(results), stats={"time_s": time.perf_counter() - t_start,
                                                                        "reached": {r.hands: r.stats.get("search_iterations", 0)
                                                                                    for r, _ in results}})

    if hands_choice == "auto":
        progress(0.05, "surveying hand configurations (auto)")
        t_survey = time.perf_counter()
        try:
            order, survey_doc = auto_order(task, termination.should_stop)
            data.timings["auto_survey_s"] = time.perf_counter() - t_survey
        except Canceled:
            if should_stop():
                raise
            return _infeasible(task, scenario, "TIMEOUT",
                               f"{termination.budget_text()} ended the survey that hands: auto needs "
                               f"(the task's survey is not cached yet): run `regrasp survey` on this scenario once "
                               f"(its answer is cached for every later plan), or choose the hands",
                               stats={"time_s": time.perf_counter() - t_start})
    else:
        order = [hands_choice]
    results: list[tuple[PlannerResult, HandConfigPlanner]] = []
    solved: list[tuple[PlannerResult, HandConfigPlanner]] = []
    ran_out = False
    for k, hands in enumerate(order):
        planner = HandConfigPlanner(task, hands, termination, data=data)
        base = 0.1 + 0.8 * k / len(order)
        span = 0.8 / len(order)

        def on_iter(i: int, failures: dict, base=base, span=span, hands=hands) -> None:
            progress(base + span * min(i / scenario.limits.max_iterations, 1.0) * 0.5,
                     f"{hands}: search iteration {i}: {failures_in_words(failures, 'states removed')}")

        if termination.past_deadline():
            ran_out = True
            break
        try:
            res = planner.plan(on_iteration=on_iter, solutions=options.solutions)
        except Canceled:
            if should_stop():
                raise
            ran_out = True  # the deadline passed inside screening or a motion
            break
        if res.status == "solved":
            progress(base + span * 0.9, f"{hands}: assembling the trajectory")
        results.append((res, planner))
        if res.status == "solved":
            solved.append((res, planner))
            if options.solutions <= len(solved) and hands_choice != "auto":
                break
            if hands_choice == "auto":
                break
    stats: dict[str, Any] = {
        "time_s": None, "setup": {**task.setup_timings, **data.timings}, "grasp_cache_hit": dict(task.grasp_cache_hit),
        "grasps": {s: len(g) for s, g in task.grasps.items()}, "placements": len(task.placements),
        "handover_poses": data.handover_poses_known, "seed": scenario.seed,
        "configurations": {r.hands: {"status": r.status, "failures": r.failures, **r.stats} for r, _ in results},
        "counters": dict(data.counters), "library_versions": library_versions(),
    }
    if survey_doc is not None:
        stats["survey"] = {row["hands"]: row.get("ratio") for row in survey_doc["rows"]}
        stats["survey_recommendation"] = survey_summary(survey_doc)
    if not solved:
        if ran_out or not results:
            return timed_out(results)
        res, planner = results[-1]
        code, message = _code_for(res, planner)
        stats["time_s"] = time.perf_counter() - t_start
        return _infeasible(task, scenario, code, message, _failure_counts(results), hands=order[-1] if len(order) == 1 else None, stats=stats)
    best, planner = min(solved, key=lambda rp: rp[0].cost)
    t_timing = time.perf_counter()
    dt = task.settings.timing.dt_s
    timing = PlanTimer(task, timing_settings(scenario, task.settings.plan_timing), scenario.speed_scale, zmp_margin_m,
                       dt, checker=data.checker).time_plan(best.pieces)
    stats["timing"] = {**timing.stats, "time_s": time.perf_counter() - t_timing}
    t_asm = time.perf_counter()
    traj = assemble(timing.pieces, task.evaluator, dt, task.placements[task.start_id])
    duration = float(traj.t[-1])
    timing_record = {**timing.record, "time_optimal_duration_s": duration - timing.stats["slack_s"], "duration_s": duration}
    traj.effort_ratio = effort_ratios(traj, task.limits or EffortEvaluator(task.robot, task.stance, task.obj.mass_kg,
                                                                           task.obj.com_local))
    stats["limits"] = task.limits is not None
    stats["assembly_s"] = time.perf_counter() - t_asm
    stats["time_s"] = time.perf_counter() - t_start
    stats["failures"] = dict(best.failures)
    stats["cost"] = best.cost
    elapsed = stats["time_s"]
    counters = data.counters
    stats["rates_per_s"] = {k.replace("_states", "_checks").replace("_solves", "_solves"): v / elapsed for k, v in counters.items()}
    progress(0.99, "writing the plan")
    alternatives = []
    for r, _ in solved:
        for cost, pieces in ([(r.cost, None)] if r is not best else []) + r.others:
            margin = None
            if pieces is not None:
                alt = assemble(pieces, task.evaluator, task.settings.timing.dt_s, task.placements[task.start_id])
                margin = float(alt.margin.min())
            alternatives.append({"hands": r.hands, "cost": cost, "min_margin_m": margin})
    alternatives.sort(key=lambda a: a["cost"])
    return {
        "schema": PLAN_SCHEMA,
        "status": "solved",
        "failure": None,
        "robot": {"name": task.robot.name, "urdf_sha256": task.robot.urdf_sha256, "joint_names": list(task.robot.joint_names)},
        "scenario": portable_dump(scenario, by_alias=True, mode="json"),
        "stance": task.stance.result().model_dump(),
        "support_polygon": task.stance.polygon.vertices.tolist(),
        "object": {"name": task.obj.name, "mass_kg": task.obj.mass_kg, "com_local": task.obj.com_local.tolist(),
                   "start_pose": list(scenario.start_pose), "goal_pose": list(scenario.goal_pose)},
        "threshold_m": task.threshold_m,
        "hands": best.hands,
        "dt_s": task.settings.timing.dt_s,
        "trajectory": trajectory_points(traj),
        "segments": traj.segments,
        "min_margin_m": float(traj.margin.min()),
        "timing": timing_record,
        "alternatives": alternatives,
        "stats": stats,
    }


def plan_job(request: dict[str, Any], ctx) -> dict[str, Any]:
    """The service's plan job: docs/contract.md section 5 request -> plan document (a ``hands: auto`` plan takes the
    request's survey fields for its survey, so it follows the same answer as the survey job)."""
    scenario = resolve_scenario(request["scenario"], survey=survey_overrides(request))
    options = PlanOptions(hands=request.get("hands"), threshold_m=request.get("threshold_m"), seed=request.get("seed"),
                          stance=request.get("stance"), time_limit_s=request.get("time_limit_s"),
                          robot=request.get("robot"), speed_scale=request.get("speed_scale"))

    def stop() -> bool:
        return bool(ctx.cancelled())

    return plan_scenario(scenario, options, progress=ctx.progress, should_stop=stop)
