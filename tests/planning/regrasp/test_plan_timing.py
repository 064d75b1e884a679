"""The plan's timing end to end on a small task: blended through its waypoints and checked again at the samples,
at rest where the hands change what they hold, faster than rest-to-rest, and slower by the speed scale."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from plan_checker import check_plan

from planner import forking
from planner.jobs.plan_job import PlanOptions, plan_scenario
from planner.motion.topp import BlendedPath
from planner.regrasp.plan_assembly import assemble
from planner.regrasp.timing.plan_timer import PlanTimer
from planner.regrasp.timing.runs import Run
from planner.regrasp.timing.settings import PlanTimingSettings
from planner.scene.scenarios import load_scenario

DATA = Path(__file__).resolve().parents[2] / "data"


def _timed(task, pieces, speed_scale=1.0, **settings):
    timing = PlanTimer(task, PlanTimingSettings(**settings), speed_scale, task.threshold_m, 0.005).time_plan(pieces)
    return timing, assemble(timing.pieces, task.evaluator, 0.005, task.placements[task.start_id])


def test_the_blended_path_is_collision_free_and_keeps_the_margin_at_every_sample(solved):
    task, pieces = solved
    timing, traj = _timed(task, pieces)
    assert timing.stats["blends"] > 0 and timing.stats["fallback_runs"] == 0
    for seg in traj.segments:  # every sample through the collision world, with the object where the plan has it
        rows = np.arange(seg["first"], seg["last"] + 1)
        holding = traj.holding[seg["first"]]
        assert all(traj.holding[i] == holding for i in rows[:-1])
        grasping = seg["hand"] if seg["kind"] in ("approach", "retreat") and seg["hand"] in ("left", "right") else None
        if holding == "none":
            res = task.world.check_batch(task.stance.base_pose, traj.Q[rows], grasping=grasping,
                                         free_object_pose=traj.object_pose[rows])
        else:
            side = "left" if holding == "both" else holding
            res = task.world.check_batch(task.stance.base_pose, traj.Q[rows], held=[(side, np.eye(4))],
                                         held_object_poses=traj.object_pose[rows], grasping=grasping)
        assert not res.collides.any(), f"{seg['kind']} collides at sample {rows[np.argmax(res.collides)]}"
    assert traj.margin.min() >= task.threshold_m - 1e-4  # the midpoints: the plan checker, below


def test_the_robot_rests_where_the_hands_change_what_they_hold_and_nowhere_else_needed(solved):
    task, pieces = solved
    _, traj = _timed(task, pieces)
    Q, holding = traj.Q, np.array(traj.holding)
    changes = np.flatnonzero(holding[1:] != holding[:-1]) + 1  # grasp and release
    assert len(changes) == 2
    for i in changes:
        assert np.array_equal(Q[i - 1], Q[i]) and np.array_equal(Q[i], Q[i + 1])
    assert np.array_equal(Q[0], Q[1]) and np.array_equal(Q[-1], Q[-2])
    # between the rests the arm does not stop: a run of zero velocity is a rest the task needs (grasp, release, a jaw)
    speed = np.abs(np.diff(Q, axis=0)).max(axis=1)
    stops = np.flatnonzero((speed[1:] == 0) & (speed[:-1] > 0)) + 1
    jaw = np.concatenate([task.jaw[s] for s in ("left", "right")])
    jaw_moves = np.flatnonzero(np.abs(np.diff(Q[:, jaw], axis=0)).max(axis=1) > 0)
    allowed = set(changes.tolist()) | {len(Q) - 1}
    for i in stops:
        near_jaw = jaw_moves.size and np.abs(jaw_moves - i).min() <= 2
        assert i - 1 in allowed or i in allowed or i + 1 in allowed or near_jaw, f"a stop at sample {i}"


def test_blending_makes_the_plan_faster_than_rest_to_rest_and_the_speed_scale_slower(solved):
    task, pieces = solved
    before = assemble(pieces, task.evaluator, 0.005, task.placements[task.start_id]).t[-1]
    timing, traj = _timed(task, pieces)
    assert traj.t[-1] < before
    _, half = _timed(task, pieces, speed_scale=0.5)
    assert half.t[-1] == pytest.approx(2 * traj.t[-1], rel=0.05)


def test_the_plan_records_its_timing_and_passes_the_checker():
    scenario = load_scenario(DATA / "small-box.yaml")
    plan = plan_scenario(scenario, PlanOptions(speed_scale=0.8))
    timing = plan["timing"]
    assert timing["method"] == "topp-ra" and timing["speed_scale"] == 0.8
    assert timing["duration_s"] == plan["trajectory"][-1]["t"]
    assert timing["time_optimal_duration_s"] < timing["duration_s"]
    assert timing["zmp_margin_m"] == plan["threshold_m"]
    stage = plan["stats"]["timing"]  # the stage's time, the quicker paths' share of it included
    assert 0.0 < stage["quicker_paths_time_s"] <= stage["time_s"] <= plan["stats"]["time_s"]
    report = check_plan(plan)
    assert report.errors == []


def test_a_motions_paths_are_ranked_by_their_timing_not_by_the_time_at_the_velocity_limits(solved, monkeypatch):
    """Two paths with the same time at the velocity limits: one turns once, the other nineteen times. The corners
    cost the second far more time, and the ranking that picks the path to time sees it."""
    from planner.motion.smoothing import path_length

    task, pieces = solved
    k = next(i for i, p in enumerate(pieces) if p.path is not None and len(p.path) > 2)
    q0 = np.asarray(pieces[k].path[0], dtype=float)
    j1, j2 = task.robot.joint_index("RSP"), task.robot.joint_index("REP")
    one_turn = np.array([q0, q0, q0])
    one_turn[1, j1] += 0.6
    one_turn[2, j1] += 0.6
    one_turn[2, j2] -= 0.6
    stairs = np.repeat(q0[None], 21, axis=0)
    for i in range(1, 21):
        stairs[i] = stairs[i - 1]
        stairs[i, j1 if i % 2 else j2] += 0.06 if i % 2 else -0.06
    timer = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005)
    weights = 1.0 / timer.vlim
    assert path_length(stairs, weights) == pytest.approx(path_length(one_turn, weights))
    alone = Run([pieces[k]], "none", None, task.placements[task.start_id])
    assert timer._estimated_time(stairs, alone) > timer._estimated_time(one_turn, alone) + 0.5

    monkeypatch.setattr(PlanTimer, "_replans", lambda self, P, validity, rng, w: [stairs, one_turn])
    monkeypatch.setattr(PlanTimer, "_via_paths", lambda self, P, validity, rng, w: [])
    monkeypatch.setattr(PlanTimer, "_box_via_paths", lambda self, k, P, found, validity, w: [])
    plain = dict(shortcut_iterations=0, partial_shortcut_iterations=0, corner_easing_sweeps=0)  # the ranking alone
    ranked = PlanTimer(task, PlanTimingSettings(**plain), 1.0, task.threshold_m, 0.005).alternatives(pieces)
    assert np.array_equal(ranked[0][k].path, one_turn) and np.array_equal(ranked[1][k].path, stairs)
    unranked = PlanTimer(task, PlanTimingSettings(rank_by_timing=False, **plain), 1.0, task.threshold_m,
                         0.005).alternatives(pieces)
    # unranked: the order of the time at the velocity limits, equal here to rounding (ties in the given order)
    assert np.array_equal(unranked[0][k].path, min((stairs, one_turn), key=lambda Q: path_length(Q, weights)))


def _refuse_also(timer: PlanTimer, refused, monkeypatch) -> None:
    """The timer's state checker refuses the states ``refused(Q)`` marks (N,) too: an obstacle in joint space."""
    real = timer.checker.validity

    def validity(hold, free_object, grasping=None, active=None):
        check = real(hold, free_object, grasping, active=active)

        def ok(Q):
            good, margin = check(Q)
            return good & ~refused(np.atleast_2d(Q)), margin
        return ok
    monkeypatch.setattr(timer.checker, "validity", validity)


def test_the_ranking_times_a_path_with_the_blends_its_checks_leave_it(solved, monkeypatch):
    """Two paths that are the same turn, in two pairs of joints: unchecked, they time alike. An obstacle inside the
    first one's corner (a box of states the checker refuses) leaves that corner only a small blend (its corner not
    pushed out: ``corner_push`` off; the next test pushes it), and the ranking
    sees the time it costs: the second path is ranked first. A path through the obstacle is never ranked (its
    time is infinite)."""
    task, pieces = solved
    k = next(i for i, p in enumerate(pieces) if p.path is not None and len(p.path) > 2)
    q0 = np.asarray(pieces[k].path[0], dtype=float)
    j = {n: task.robot.joint_index(n) for n in ("RSP", "REP", "RSY", "RWRY")}

    def turn(first: str, second: str) -> np.ndarray:
        P = np.array([q0, q0, q0])
        P[1:, j[first]] += 0.6
        P[2, j[second]] -= 0.6
        return P

    hugging, clear = turn("RSP", "REP"), turn("RSY", "RWRY")
    timer = PlanTimer(task, PlanTimingSettings(corner_push=False), 1.0, task.threshold_m, 0.005)

    def inside(Q: np.ndarray) -> np.ndarray:
        return ((Q[:, j["RSP"]] - q0[j["RSP"]] > 0.3) & (Q[:, j["RSP"]] - q0[j["RSP"]] < 0.59)
                & (q0[j["REP"]] - Q[:, j["REP"]] > 0.01) & (q0[j["REP"]] - Q[:, j["REP"]] < 0.3))

    alone = Run([pieces[k]], "none", None, task.placements[task.start_id])
    unchecked = PlanTimer(task, PlanTimingSettings(path_check_rad=0.0), 1.0, task.threshold_m, 0.005)
    assert unchecked._estimated_time(hugging, alone) == pytest.approx(unchecked._estimated_time(clear, alone), rel=0.05)
    clear_time = timer._estimated_time(clear, alone)
    _refuse_also(timer, inside, monkeypatch)
    assert timer._estimated_time(hugging, alone) > timer._estimated_time(clear, alone) + 0.05
    assert timer._estimated_time(clear, alone) == clear_time  # the obstacle is not in its way
    through = np.array([q0, q0, q0])  # a segment straight through the obstacle: no blend can help
    through[1:, j["RSP"]] += 1.04
    through[1:, j["REP"]] -= 0.16
    through[2, j["RSY"]] += 0.3
    assert timer._estimated_time(through, alone) == float("inf")
    assert timer.stats["refused"] == [] and timer.stats["blends_removed"] == 0  # a ranking's trials are not counted

    monkeypatch.setattr(PlanTimer, "_replans", lambda self, P, validity, rng, w: [hugging, clear])
    monkeypatch.setattr(PlanTimer, "_via_paths", lambda self, P, validity, rng, w: [])
    monkeypatch.setattr(PlanTimer, "_box_via_paths", lambda self, k, P, found, validity, w: [])
    checker = timer.checker  # the one with the obstacle, for the timer below too
    monkeypatch.setattr(PlanTimer, "checker", property(lambda self: checker))
    plain = dict(shortcut_iterations=0, partial_shortcut_iterations=0, corner_push=False, corner_easing_sweeps=0)
    ranked = PlanTimer(task, PlanTimingSettings(**plain), 1.0, task.threshold_m, 0.005).alternatives(pieces)
    assert np.array_equal(ranked[0][k].path, clear) and np.array_equal(ranked[1][k].path, hugging)


def test_a_corner_whose_blend_an_obstacle_shrinks_is_pushed_out_and_keeps_its_blend(solved, monkeypatch):
    """A turn in two joints far from their limits with an obstacle inside its corner (a box of states the checker
    refuses): its blend shrinks to nothing, and the robot stops there. Pushed out (``corner_push``, the default), the
    corner moves away from the inside of the turn and keeps a large blend, every state of its path (recomputed
    here every 1 mrad) misses the obstacle, and it times well below the stop (not as fast as the turn with no
    obstacle: the legs are longer). With a second obstacle just outside the first leg near the corner, where a pushed
    leg goes, no push passes: the shrunk blend stands, the corner where it was, exactly as without pushing."""
    task, pieces = solved
    k = next(i for i, p in enumerate(pieces) if p.path is not None and len(p.path) > 2)
    q0 = np.asarray(pieces[k].path[0], dtype=float)
    sp, ep = task.robot.joint_index("RSY"), task.robot.joint_index("RWRY")
    P = np.array([q0, q0, q0])
    P[1:, sp] += 0.6
    P[2, ep] -= 0.6

    def inside(Q: np.ndarray) -> np.ndarray:
        return ((Q[:, sp] - q0[sp] > 0.3) & (Q[:, sp] - q0[sp] < 0.59)
                & (q0[ep] - Q[:, ep] > 0.01) & (q0[ep] - Q[:, ep] < 0.3))

    def outside(Q: np.ndarray) -> np.ndarray:  # the inside box mirrored across the first leg
        return ((Q[:, sp] - q0[sp] > 0.3) & (Q[:, sp] - q0[sp] < 0.59)
                & (Q[:, ep] - q0[ep] > 0.01) & (Q[:, ep] - q0[ep] < 0.3))

    run = Run([replace(pieces[k], path=P)], "none", None, task.placements[task.start_id])
    asked = np.full(1, PlanTimingSettings().blend_rad)

    def timers(refused):
        pushing = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005)
        shrinking = PlanTimer(task, PlanTimingSettings(corner_push=False), 1.0, task.threshold_m, 0.005)
        for timer in (pushing, shrinking):
            _refuse_also(timer, refused, monkeypatch)
        return pushing, shrinking

    pushing, shrinking = timers(inside)
    W, blends = pushing._checked_blends(run, P, [0], asked, count=False)
    W_shrunk, shrunk = shrinking._checked_blends(run, P, [0], asked, count=False)
    assert shrunk[0] < asked[0] / 2 and np.array_equal(W_shrunk, P)
    assert blends[0] >= asked[0] / 4 > 2 * shrunk[0]  # pushed, it keeps a blend many times the shrunk one
    moved = W[1] - P[1]
    assert moved[sp] > 0.01 and moved[ep] > 0.01  # away from the inside of the turn
    assert np.array_equal(W[[0, 2]], P[[0, 2]])  # the rests where they were
    path = BlendedPath(W, blends, True)
    Q = path(np.linspace(0.0, path.length, int(np.ceil(path.length / 0.001)) + 1))
    assert not inside(Q).any()
    pushed_time = pushing._coarse_time(run, W, blends)
    unobstructed = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005)._coarse_time(run, P, asked)
    assert unobstructed < pushed_time < shrinking._coarse_time(run, W_shrunk, shrunk) - 0.2
    assert pushing._estimated_time(P, run) == pytest.approx(pushed_time)  # the ranking sees the pushed corner

    pushing, shrinking = timers(lambda Q: inside(Q) | outside(Q))
    W, blends = pushing._checked_blends(run, P, [0], asked, count=False)
    W_shrunk, shrunk = shrinking._checked_blends(run, P, [0], asked, count=False)
    assert np.array_equal(W, P) and np.array_equal(blends, shrunk) and shrunk[0] < asked[0] / 2


#: What both scripts below start with: the small box task solved, and a timer counting its checks, of one process
#: (``parallel`` False) or of this one and a forked helper.
_SOLVED_TIMER = r"""
import json, sys, time
from collections import Counter
from pathlib import Path

import numpy as np

from planner import forking
from planner.forking import fork_is_safe
from planner.jobs.plan_job import build_task
from planner.regrasp.state_checker import StateChecker
from planner.regrasp.timing import plan_timer
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.timing.plan_timer import PlanTimer
from planner.regrasp.timing.settings import PlanTimingSettings
from planner.scene.scenarios import load_scenario

scenario = load_scenario(Path(sys.argv[1]))
task = build_task(scenario)
pieces = HandConfigPlanner(task, scenario.hands).plan().pieces
spare, real = forking.spare_cores, plan_timer.share_with_child


def counted_timer(parallel):
    forking.spare_cores = spare if parallel else (lambda: 0)
    counts = Counter()
    timer = PlanTimer(task, PlanTimingSettings(replans=2), 1.0, task.threshold_m, 0.005)
    timer._checker = StateChecker(task.evaluator, task.world, task.stance.base_pose, task.constrained,
                               counts, limits=task.limits)
    return timer, counts
"""

_ONE_OR_TWO = _SOLVED_TIMER + r"""
shared = []
plan_timer.share_with_child = lambda jobs, work, stop, idle=None: shared.append(len(jobs)) or real(jobs, work, stop, idle)


def found(parallel):
    timer, counts = counted_timer(parallel)
    levels = timer.alternatives(pieces)
    paths = [[None if p.path is None else np.asarray(p.path).tolist() for p in level] for level in levels]
    return paths, {k: timer.stats[k] for k in ("replans", "via_paths", "shortened_s")}, dict(counts)


one = found(False)
alone = list(shared)
two = found(True)
print(json.dumps({"fork_safe": fork_is_safe(), "alone": alone, "shared": shared, "one": one, "two": two}))
"""


def test_the_quicker_paths_are_the_same_from_one_process_or_two():
    """The planned motions' quicker paths, worked on in this process and a forked helper at once, are the paths one
    process finds, bit for bit, and the helper's checks are counted. Run in a fresh interpreter: a test process may
    hold threads from earlier tests (servers, sessions), and the planner rightly does not fork beside them."""
    import json
    import subprocess
    import sys

    from planner.forking import spare_cores

    if spare_cores() == 0:
        pytest.skip("one core: the planner never forks a helper here")
    out = subprocess.run([sys.executable, "-c", _ONE_OR_TWO, str(DATA / "small-box.yaml")], capture_output=True,
                         text=True, timeout=600, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["fork_safe"] and res["alone"] == []
    assert res["shared"] and res["shared"][0] >= 2  # the planned motions went to the two processes
    (one_paths, one_stats, one_counts), (two_paths, two_stats, two_counts) = res["one"], res["two"]
    assert one_paths == two_paths and any(p is not None for level in one_paths for p in level)
    assert one_stats == two_stats and one_stats["replans"] > 0
    assert one_counts == two_counts and one_counts["collision_states"] > 0


_TIMED_EARLY = _SOLVED_TIMER + r"""
def slow_helper(jobs, work, stop, idle=None):
    # the helper starts its jobs late, so that this process waits for it with runs it can time meanwhile
    def late(job, in_child):
        if in_child:
            time.sleep(1.0)
        return work(job, in_child)
    return real(jobs, late, stop, idle)


plan_timer.share_with_child = slow_helper
early = []
real_early = PlanTimer._time_early
PlanTimer._time_early = lambda self, *a: (early.append(real_early(self, *a)) or early[-1])


def timed(parallel):
    timer, counts = counted_timer(parallel)
    out = timer.time_plan(pieces)
    walls = ("time_s", "quicker_paths_time_s", "early_timing_s")
    return ([np.asarray(p.waypoints).tolist() for p in out.pieces], {k: v for k, v in out.stats.items() if k not in walls},
            dict(counts), out.stats.get("early_timing_s", 0.0))


one = timed(False)
two = timed(True)
print(json.dumps({"one": one, "two": two, "early": early}))
"""


def test_runs_timed_while_the_helper_works_give_the_plan_one_process_gives():
    """With the helper slow to start its motions, this process times the runs whose paths it has found while it
    waits (``early_timing_s``): the timed pieces, the timing's stats and the check counts are those of one process
    alone, bit for bit."""
    import json
    import subprocess
    import sys

    from planner.forking import spare_cores

    if spare_cores() == 0:
        pytest.skip("one core: the planner never forks a helper here")
    out = subprocess.run([sys.executable, "-c", _TIMED_EARLY, str(DATA / "small-box.yaml")], capture_output=True,
                         text=True, timeout=600, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    (one_pieces, one_stats, one_counts, one_early), (two_pieces, two_stats, two_counts, two_early) = res["one"], res["two"]
    assert one_early == 0.0 and two_early > 0.0 and True in res["early"]  # runs were timed early, with two only
    assert one_pieces == two_pieces and len(one_pieces) > 1
    assert one_stats == two_stats and one_stats["runs"] > 0
    assert one_counts == two_counts and one_counts["collision_states"] > 0


_RUNS_SHARED = _SOLVED_TIMER + r"""
shared = []
real_runs = plan_timer.share_with_child
broken = False


def counted_share(jobs, work, stop, idle=None):
    shared.append(len(jobs))
    done = []

    def breaking(job, in_child):  # with ``broken``, the helper fails at its first run, which it has time to claim
        if broken and in_child:
            raise RuntimeError("the helper is lost")
        if broken and not done:
            time.sleep(1.0)
        done.append(in_child)
        return work(job, in_child)
    return real_runs(jobs, breaking, stop, idle)


plan_timer.share_with_child = counted_share


def timed(parallel):
    timer, counts = counted_timer(parallel)
    out = timer.time_plan(pieces)
    walls = ("time_s", "quicker_paths_time_s", "early_timing_s")
    return ([np.asarray(p.waypoints).tolist() for p in out.pieces], {k: v for k, v in out.stats.items() if k not in walls},
            dict(counts))


one = timed(False)
alone = list(shared)
two = timed(True)
broken = True
lost = timed(True)
print(json.dumps({"one": one, "two": two, "lost": lost, "alone": alone, "shared": shared[len(alone):]}))
"""


def test_runs_timed_in_this_process_and_the_helper_at_once_give_the_plan_one_process_gives():
    """After the quicker paths, the runs' timings are shared with a forked helper (both timings, the reserve cap's
    second one too): the timed pieces, the timing's stats and the check counts are those of one process alone, bit
    for bit, and the helper's checks are counted. A helper lost on the way leaves its runs to this process: the
    same plan, the loss in ``helper_errors``."""
    import json
    import subprocess
    import sys

    from planner.forking import spare_cores

    if spare_cores() == 0:
        pytest.skip("one core: the planner never forks a helper here")
    out = subprocess.run([sys.executable, "-c", _RUNS_SHARED, str(DATA / "small-box.yaml")], capture_output=True,
                         text=True, timeout=600, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["alone"] == [] and res["shared"] and max(res["shared"]) >= 2  # runs went to the two processes
    (one_pieces, one_stats, one_counts), (two_pieces, two_stats, two_counts) = res["one"], res["two"]
    assert one_pieces == two_pieces and len(one_pieces) > 1
    assert one_stats == two_stats and one_stats["runs"] > 0 and "helper_errors" not in two_stats
    assert one_counts == two_counts and one_counts["collision_states"] > 0
    lost_pieces, lost_stats, lost_counts = res["lost"]
    assert lost_pieces == one_pieces
    assert set(lost_stats.pop("helper_errors")) == {"RuntimeError: the helper is lost"}
    assert lost_stats == one_stats and lost_counts == one_counts


def test_a_run_goes_along_the_spline_where_it_is_quicker_and_every_state_of_it_passes_the_checks(solved, monkeypatch):
    """The runs of the search's own pieces with a corner, timed with and without the spline: the quicker is kept,
    and the spline is quicker on one at least. With an obstacle that refuses every state more than
    ``tol`` from the waypoints' polyline, the spline is pulled towards the corners until its states pass or the
    blended run stands: either way every sample of the run is within ``tol``; with a tolerance nothing but the
    polyline itself meets, no spline run is kept."""
    from planner.regrasp.timing.runs import off_path, runs_of, waypoints_of

    task, pieces = solved
    quicker = []
    for run in (r for r in runs_of(pieces, task) if len(waypoints_of(r)[0]) > 2):
        blended = PlanTimer(task, PlanTimingSettings(spline_runs=False), 1.0, task.threshold_m, 0.005)
        splined = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005)
        plain, timed = blended.time_run(run), splined.time_run(run)
        assert timed[2] <= plain[2]  # the quicker of the two (on the coarse grid, and here in full)
        if splined.stats["spline_runs"]:
            assert timed[2] < plain[2]
            quicker.append((plain[2] - timed[2], run))
    assert quicker and max(quicker, key=lambda q: q[0])[0] > 0.05
    run = max(quicker, key=lambda q: q[0])[1]
    W = waypoints_of(run)[0]

    def hugging(tol: float) -> PlanTimer:
        timer = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005)
        _refuse_also(timer, lambda Q: off_path(Q, W, tol), monkeypatch)
        return timer

    for tol, spline_kept in ((0.03, None), (1e-6, False)):
        timer = hugging(tol)
        timed = timer.time_run(run)
        assert timed is not None
        Q = np.vstack(timed[0])
        assert not off_path(Q, W, tol + 1e-9).any()
        if spline_kept is not None:
            assert bool(timer.stats["spline_runs"]) is spline_kept


def test_the_reserves_cap_comes_from_a_first_timing_of_the_plan(solved):
    """With the cap on, the runs are timed twice: the first timing is the uncapped one, and its smallest static
    margin caps the second's reserve; the stats count the runs once."""
    from planner.regrasp.plan_assembly import object_states

    task, pieces = solved
    plain = PlanTimer(task, PlanTimingSettings(zmp_reserve_cap_share=None), 1.0, task.threshold_m, 0.005)
    first = plain.time_plan(pieces)
    least = min(float(task.evaluator.evaluate(np.asarray(p.waypoints), hold, threshold_m=0.0).margin.min())
                for p, _, hold, _ in object_states(first.pieces, task.evaluator, task.placements[task.start_id]))
    capped = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005)
    timing = capped.time_plan(pieces)
    assert capped.plan_static_min_m == pytest.approx(least, abs=1e-12)
    assert timing.stats["reserve_cap_m"] == pytest.approx(0.75 * least + 0.019)
    assert timing.stats["runs"] == first.stats["runs"] and "reserve_cap_m" not in first.stats
    assert sum(len(p.waypoints) for p in timing.pieces) <= sum(len(p.waypoints) for p in first.pieces)



def test_the_caps_second_timing_recomputes_only_the_runs_whose_reserve_the_cap_changes(solved, monkeypatch):
    """The second timing takes a run's first timing again where every ZMP reserve it asked is under the cap, and
    times again the others: the same pieces and stats, bit for bit, as timing every run twice; a cap under every
    reserve (share 0, no overshoot) times every run again, a cap over all of them (the overshoot alone 1 m) none."""
    task, pieces = solved
    monkeypatch.setattr(forking, "spare_cores", lambda: 0)  # no helper: every run is timed where it is counted

    def timed(recompute: bool, **settings) -> tuple[PlanTimer, object, list[tuple[float, int]], list[list[float]]]:
        timer = PlanTimer(task, PlanTimingSettings(**settings), 1.0, task.threshold_m, 0.005)
        calls, asked, inside = [], [], []
        run_once, time_run, floor = PlanTimer._once, PlanTimer.time_run, PlanTimer._zmp_floor

        def counted(self, run):
            calls.append((self._reserve_cap(), id(run)))
            asked.append([])
            inside.append(run)
            try:
                return time_run(self, run)
            finally:
                inside.pop()

        def floor_asked(self, static_margin):
            if inside:  # not the ranking's, before any run is timed
                asked[-1].append(self.reserve_share * float(np.maximum(static_margin, 0.0).min()))
            return floor(self, static_margin)

        with monkeypatch.context() as m:
            m.setattr(PlanTimer, "time_run", counted)
            m.setattr(PlanTimer, "_zmp_floor", floor_asked)
            if recompute:
                m.setattr(PlanTimer, "_once", lambda self, key, compute: compute())
            else:
                m.setattr(PlanTimer, "_once", run_once)
            timing = timer.time_plan(pieces)
        return timer, timing, calls, asked

    _, every, every_calls, _ = timed(True)
    timer, kept, calls, asked = timed(False)
    assert [np.asarray(p.waypoints).tobytes() for p in kept.pieces] == [np.asarray(p.waypoints).tobytes()
                                                                        for p in every.pieces]
    walls = ("quicker_paths_time_s", "early_timing_s")
    assert {k: v for k, v in kept.stats.items() if k not in walls} == {
        k: v for k, v in every.stats.items() if k not in walls}
    cap = kept.stats["reserve_cap_m"]
    first = [(run, a) for (c, run), a in zip(calls, asked) if c == np.inf]
    again = [run for c, run in calls if c != np.inf]
    assert first and len(calls) < len(every_calls)
    assert again == [run for run, a in first if max(a, default=0.0) > cap]  # exactly those the cap lowers
    assert timer._kept == {}  # nothing kept past the plan

    for settings, times_again in (({"zmp_reserve_cap_share": 0.0, "zmp_overshoot_m": 0.0}, True),
                                  ({"zmp_overshoot_m": 1.0}, False)):
        _, _, calls, _ = timed(False, **settings)
        first = [run for c, run in calls if c == np.inf]
        assert [run for c, run in calls if c != np.inf] == (first if times_again else [])

def test_a_paths_terms_at_its_gridpoints_are_computed_once_per_plan(solved, monkeypatch):
    """The terms of a path at its TOPP-RA gridpoints that no ZMP floor changes (the CoM terms, the inertial sweep,
    the torques' rows) are kept within a plan: the reserve cap's second timing of a run solves TOPP-RA again without
    recomputing them. The same pieces and stats, bit for bit, as computing them at every timing, with fewer
    computed, and nothing kept past the plan."""
    from planner.regrasp.timing import limits

    task, pieces = solved
    monkeypatch.setattr(forking, "spare_cores", lambda: 0)  # no helper: every computation is counted here

    class Forgetful(dict):
        def __setitem__(self, key, value):  # keeps nothing: every timing computes its paths' terms
            pass

    def timed(keep: bool) -> tuple[PlanTimer, object, int]:
        timer = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005)
        if not keep:
            timer._geometries = Forgetful()
        computed = []
        terms = limits.com_path_terms
        with monkeypatch.context() as m:
            m.setattr(limits, "com_path_terms", lambda *a: computed.append(1) or terms(*a))
            timing = timer.time_plan(pieces)
        return timer, timing, len(computed)

    _, every, every_computed = timed(False)
    timer, kept, computed = timed(True)
    assert "reserve_cap_m" in kept.stats  # timed twice
    assert [np.asarray(p.waypoints).tobytes() for p in kept.pieces] == [np.asarray(p.waypoints).tobytes()
                                                                        for p in every.pieces]
    walls = ("quicker_paths_time_s", "early_timing_s")
    assert {k: v for k, v in kept.stats.items() if k not in walls} == {
        k: v for k, v in every.stats.items() if k not in walls}
    assert 0 < computed < every_computed
    assert timer._geometries == {}


def _detour(P: np.ndarray, joint: int, rad: float) -> np.ndarray:
    """P with one joint swung out and back in the middle of its second segment (three waypoints on that segment, the
    middle one ``rad`` out): a detour of that joint alone, which costs time at the velocity limits."""
    a, b = P[1], P[2]
    bump = np.array([a + 0.25 * (b - a), a + 0.5 * (b - a), a + 0.75 * (b - a)])
    bump[1, joint] += rad
    return np.vstack([P[:2], bump, P[2:]])


def test_every_path_of_a_motion_is_partially_shortcut_before_the_ranking(solved, monkeypatch):
    """A replanned path that is not the quickest, with one joint's detour (the idle left elbow swung out and back):
    among the ``shortened_paths`` quickest, it gets the same partial shortcuts as the quickest one and comes out without the detour, so the ranking
    compares paths shortened alike. Without the partial shortcuts the detour stays (the test's control)."""
    from planner.motion.smoothing import path_length

    task, pieces = solved
    k = next(i for i, p in enumerate(pieces) if p.path is not None and len(p.path) > 2)
    own = np.asarray(pieces[k].path, dtype=float)
    j = task.robot.joint_index("LEP")
    assert np.ptp(own[:, j]) == 0.0  # the right hand's motion: the left elbow stays
    detour = _detour(own, j, 0.4)
    timer = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005)
    weights = 1.0 / timer.vlim
    assert path_length(detour, weights) > path_length(own, weights) + 0.05

    monkeypatch.setattr(PlanTimer, "_replans", lambda self, P, validity, rng, w: [own, detour])
    monkeypatch.setattr(PlanTimer, "_via_paths", lambda self, P, validity, rng, w: [])
    monkeypatch.setattr(PlanTimer, "_box_via_paths", lambda self, k, P, found, validity, w: [])

    def alternatives(**settings):
        timing = PlanTimingSettings(shortcut_iterations=0, rank_by_timing=False, corner_easing_sweeps=0, **settings)
        return PlanTimer(task, timing, 1.0, task.threshold_m, 0.005).alternatives(pieces)

    levels = alternatives()
    assert len(levels) == 2
    for level in levels:
        Q = level[k].path
        assert np.array_equal(Q[0], own[0]) and np.array_equal(Q[-1], own[-1])
        assert np.ptp(Q[:, j]) == 0.0, "a path kept its detour"
    plain = alternatives(partial_shortcut_iterations=0)
    assert np.array_equal(plain[1][k].path, detour)
    first_only = alternatives(shortened_paths=1)
    assert np.array_equal(first_only[1][k].path, detour)  # only the quickest path is shortened when one is asked for


def test_the_alternatives_are_the_seeds(solved):
    """The replans and every path's shortening draw from the seed's stream in a fixed order: the same seed gives the
    same paths, to the bit."""
    task, pieces = solved
    settings = PlanTimingSettings(replans=2, rank_by_timing=False)
    first, second = (PlanTimer(task, settings, 1.0, task.threshold_m, 0.005).alternatives(pieces) for _ in range(2))
    assert len(first) == len(second)
    for a, b in zip(first, second):
        for p, q in zip(a, b):
            assert (p.path is None) == (q.path is None)
            assert p.path is None or np.array_equal(p.path, q.path)


def test_a_motions_best_path_is_eased_where_that_makes_it_quicker(solved, monkeypatch):
    """A motion's own path, with a zig-zag of the idle left elbow added (three waypoints swung out and back): its
    corners cost time. With corner easing the eased path comes first, the same ends, every state of it valid by the
    task's own checks (densely, here), quicker by the ranking's estimate, and the path it came from second; without
    easing, that path is first (the test's control). After its second pass (the default's last) this zig-zag's eased
    path fails the blend checks of the ranking's estimate: the first pass's path, which passes them, is kept."""
    from planner.motion.interpolation import densify

    task, pieces = solved
    k = next(i for i, p in enumerate(pieces) if p.path is not None and len(p.path) > 2)
    own = np.asarray(pieces[k].path, dtype=float)
    j = task.robot.joint_index("LEP")
    assert np.ptp(own[:, j]) == 0.0  # the right hand's motion: the left elbow stays
    zigzag = _detour(_detour(own, j, 0.3), j, -0.3)
    monkeypatch.setattr(PlanTimer, "_replans", lambda self, P, validity, rng, w: [zigzag])
    monkeypatch.setattr(PlanTimer, "_via_paths", lambda self, P, validity, rng, w: [])
    monkeypatch.setattr(PlanTimer, "_box_via_paths", lambda self, k, P, found, validity, w: [])

    def timer(**settings):
        return PlanTimer(task, PlanTimingSettings(shortcut_iterations=0, partial_shortcut_iterations=0, **settings),
                         1.0, task.threshold_m, 0.005)

    easing = timer()
    levels = easing.alternatives(pieces)
    assert len(levels) == 2 and np.array_equal(levels[1][k].path, zigzag)
    eased = levels[0][k].path
    assert np.array_equal(eased[0], own[0]) and np.array_equal(eased[-1], own[-1]) and eased.shape == zigzag.shape
    assert not np.array_equal(eased, zigzag) and easing.stats["easing_moves"] > 0
    alone = Run([pieces[k]], "none", None, task.placements[task.start_id])
    assert easing._estimated_time(eased, alone) < easing._estimated_time(zigzag, alone) - 0.05
    validity = easing.checker.validity(None, task.placements[task.start_id], None)
    assert validity(densify(eased, 0.005))[0].all()
    control = timer(corner_easing_sweeps=0).alternatives(pieces)
    assert len(control) == 1 and np.array_equal(control[0][k].path, zigzag)
