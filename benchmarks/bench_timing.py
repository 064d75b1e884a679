"""Timing of one solved plan three ways: the search's rest-to-rest trapezoids, jerk-limited rest-to-rest profiles
(ruckig, phase-synchronised so each segment stays straight), and the plan timing (TOPP-RA through blended
waypoints under the joint, torque and ZMP limits) with moving-average shaping windows of several lengths.

Prints per method the motion duration, the time the timing took, the largest joint jerk (third finite difference
at the plan's 5 ms period), the largest distance of the ZMP from the CoM, the smallest ZMP margin, and the number
of stops (samples where every joint is at rest after moving). Figures are from this machine; the duration and the
balance figures depend on the seed only.

Then the plan timing's runs (rest to rest), each with its duration and its corner-free floor: the time of the run's
chosen path at the velocity limits (``velocity_scale`` of them), plus one start from rest and one stop at rest
(the largest v / a of its moving joints; a run too short to reach full speed, 2 sqrt(d / a) of its slowest joint).
The floor leaves out every corner and the balance: what is left above it is what corners, blends and the ZMP cost,
and what a shorter path (other key postures) could still win. It is the floor of the waypoints' polyline: a run laid
along the spline of its waypoints cuts their corners and can come in under it. Beside it, the floor of the run made
straight between its pieces' ends (the key postures the task fixes: a grasp's approach, the handover's exchange): no
path through those postures is quicker at the velocity limits, so what lies between the two floors is what the
paths' detours (round the table, past the body) cost.

    python benchmarks/bench_timing.py --scenario upright --hands left-left
    python benchmarks/bench_timing.py --scenario staggered --hands left-left --seed 2
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Synchronization, Trajectory

from planner.blas_threads import one_blas_thread
from planner.jobs.plan_job import build_task
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.plan_assembly import MotionPiece, assemble
from planner.regrasp.timing.plan_timer import PlanTimer
from planner.regrasp.timing.runs import Run, runs_of, waypoints_of
from planner.scene.scenarios import load_builtin, with_overrides

DT = 0.005


def ruckig_piece(piece: MotionPiece, vmax: np.ndarray, amax: np.ndarray, jmax: np.ndarray) -> MotionPiece:
    """The piece's path, each straight segment rest to rest with ruckig's time-optimal jerk-limited profile."""
    W = np.asarray(piece.path if piece.path is not None else piece.waypoints, dtype=float)
    n = W.shape[1]
    parts = [W[:1]]
    for a, b in zip(W[:-1], W[1:]):
        moving = np.abs(b - a) > 0
        if not moving.any():
            continue
        otg = Ruckig(int(moving.sum()))
        inp = InputParameter(int(moving.sum()))
        inp.current_position, inp.target_position = a[moving].tolist(), b[moving].tolist()
        inp.current_velocity = inp.current_acceleration = [0.0] * int(moving.sum())
        inp.target_velocity = inp.target_acceleration = [0.0] * int(moving.sum())
        inp.max_velocity, inp.max_acceleration = vmax[moving].tolist(), amax[moving].tolist()
        inp.max_jerk = jmax[moving].tolist()
        inp.synchronization = Synchronization.Phase  # every joint on the same straight line
        traj = Trajectory(int(moving.sum()))
        if otg.calculate(inp, traj) not in (Result.Working, Result.Finished):
            raise RuntimeError("ruckig found no profile")
        steps = max(1, int(np.ceil(traj.duration / DT)))
        Q = np.repeat(a[None], steps, axis=0)
        for k in range(steps):
            Q[k, moving] = traj.at_time(min((k + 1) * DT * traj.duration / (steps * DT), traj.duration))[0]
        Q[-1] = b
        parts.append(Q)
    Q = np.vstack(parts)
    return MotionPiece(piece.kind, piece.hand, np.vstack([Q[:1], Q, Q[-1:]]), piece.holding, piece.hold, path=W)


def figures(task, traj) -> dict:
    Q = traj.Q
    jerk = np.abs(np.diff(Q, n=3, axis=0)).max() / DT**3 if len(Q) > 3 else 0.0
    offset = np.linalg.norm(traj.zmp - traj.com[:, :2], axis=1).max()
    speed = np.abs(np.diff(Q, axis=0)).max(axis=1)
    stops = int(np.count_nonzero((speed[1:] == 0) & (speed[:-1] > 0)))
    return {"duration_s": float(traj.t[-1]), "max_jerk_rad_s3": float(jerk), "max_zmp_offset_mm": 1000 * float(offset),
            "min_zmp_margin_mm": 1000 * float(task.evaluator.polygon.margin(traj.zmp).min()),
            "min_margin_mm": 1000 * float(traj.margin.min()), "stops": stops}


def run_floor(run: Run, vmax: np.ndarray, amax: np.ndarray) -> float:
    """The corner-free floor of one run (see the module's docstring), s."""
    return polyline_floor(waypoints_of(run)[0], vmax, amax)


def straight_floor(run: Run, vmax: np.ndarray, amax: np.ndarray) -> float:
    """The corner-free floor of the run made straight between its pieces' ends (see the module's docstring), s."""
    ends = [run.pieces[0].joint_path()[0]] + [piece.joint_path()[-1] for piece in run.pieces]
    return polyline_floor(np.array(ends), vmax, amax)


def polyline_floor(W: np.ndarray, vmax: np.ndarray, amax: np.ndarray) -> float:
    """The time along the polyline W at the velocity limits plus one start and one stop (see the module's
    docstring), s."""
    if len(W) < 2:
        return 0.0
    moving = np.ptp(W, axis=0) > 0
    if not moving.any():
        return 0.0
    at_speed = float((np.abs(np.diff(W, axis=0))[:, moving] / vmax[moving]).max(axis=1).sum())
    ramp = float((vmax[moving] / amax[moving]).max())
    travel = np.abs(np.diff(W, axis=0))[:, moving].sum(axis=0)
    short = travel < vmax[moving] ** 2 / amax[moving]  # never reaches full speed (a jaw's closing)
    if short.all():
        return float((2.0 * np.sqrt(travel / amax[moving])).max())
    return at_speed + ramp


@one_blas_thread  # as the CLI's plans run (planner/blas_threads.py)
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="upright")
    ap.add_argument("--hands", default="left-left")
    ap.add_argument("--seed", type=int, default=None, help="over the scenario's own seed")
    ap.add_argument("--jerk-per-accel", type=float, default=5.0, help="ruckig's jerk limit as a multiple of the "
                    "acceleration limit, 1/s (the robot's spec gives none)")
    ap.add_argument("--shaping", type=float, nargs="+", default=[0.0, 0.1, 0.4, 0.83],
                    help="moving-average windows of the plan timing to compare, s (0.83 s: one period of a 1.2 Hz sway)")
    args = ap.parse_args()
    scenario = load_builtin(args.scenario)
    if args.seed is not None:
        scenario = with_overrides(scenario, seed=args.seed)
    task = build_task(scenario)
    res = HandConfigPlanner(task, args.hands).plan()
    if res.status != "solved":
        raise SystemExit(f"{args.scenario} {args.hands}: {res.status}")
    start = task.placements[task.start_id]
    robot = task.robot
    rows = {}
    t0 = time.perf_counter()
    rows["trapezoid (search, rest to rest)"] = (figures(task, assemble(res.pieces, task.evaluator, DT, start)), None)
    t0 = time.perf_counter()
    pieces = [ruckig_piece(p, 0.95 * robot.velocity_limit, 0.95 * robot.acceleration_limit,
                           args.jerk_per_accel * robot.acceleration_limit) for p in res.pieces]
    took = time.perf_counter() - t0
    rows[f"ruckig (jerk {args.jerk_per_accel:g} x accel, rest to rest)"] = (
        figures(task, assemble(pieces, task.evaluator, DT, start)), took)
    runs = []
    for window in args.shaping:
        settings = task.settings.plan_timing.model_copy(update={"shaping_window_s": window})
        t0 = time.perf_counter()
        timing = PlanTimer(task, settings, 1.0, task.threshold_m, DT).time_plan(res.pieces)
        took = time.perf_counter() - t0
        traj = assemble(timing.pieces, task.evaluator, DT, start)
        rows[f"TOPP-RA, blended, shaping {window:g} s"] = (figures(task, traj), took)
        if not runs:  # the first window's runs (0: TOPP-RA's own profile)
            scale = settings.velocity_scale, settings.acceleration_scale
            vmax, amax = robot.velocity_limit * scale[0], robot.acceleration_limit * scale[1]
            for run in runs_of(timing.pieces, task):
                n = sum(len(p.waypoints) for p in run.pieces) - (len(run.pieces) - 1)
                runs.append(("+".join(p.kind for p in run.pieces), (n - 1) * DT, run_floor(run, vmax, amax),
                             straight_floor(run, vmax, amax)))
    print(f"{args.scenario} {args.hands}, seed {scenario.seed}, threshold {task.threshold_m * 1000:g} mm")
    print(f"{'method':45s} {'duration s':>10s} {'timing s':>9s} {'jerk rad/s3':>12s} {'zmp-com mm':>11s} "
          f"{'zmp margin mm':>14s} {'margin mm':>10s} {'stops':>6s}")
    for name, (f, took) in rows.items():
        print(f"{name:45s} {f['duration_s']:10.2f} {'-' if took is None else f'{took:9.2f}':>9s} "
              f"{f['max_jerk_rad_s3']:12.1f} {f['max_zmp_offset_mm']:11.1f} {f['min_zmp_margin_mm']:14.1f} "
              f"{f['min_margin_mm']:10.1f} {f['stops']:6d}")
    print(f"\nruns of the TOPP-RA plan (shaping {args.shaping[0]:g} s): duration, corner-free floor of its path and "
          f"of the straight line through its pieces' ends")
    for kinds, took, floor, straight in runs:
        print(f"  {kinds:55s} {took:6.2f} s  floor {floor:6.2f} s  straight {straight:6.2f} s")
    print(f"  {'all runs':55s} {sum(r[1] for r in runs):6.2f} s  floor {sum(r[2] for r in runs):6.2f} s  "
          f"straight {sum(r[3] for r in runs):6.2f} s")


if __name__ == "__main__":
    main()
