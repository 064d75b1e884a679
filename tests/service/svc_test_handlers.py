"""Job handlers for the service tests: real CPU work with progress and cancel polling.

The scenario name selects the behaviour (the service's name check is off in
these tests): ``busy-S`` computes hashes for S seconds, reporting progress and
polling ``ctx.cancelled()`` every few milliseconds; ``hang-S`` computes without
ever polling (only a kill stops it); ``crash`` kills its own process (SIGKILL), ``exit-N`` ends it with
``os._exit(N)``; ``robot`` reports the worker's pid and robot loads; ``move-S`` a real plan that swings the
right shoulder 0.5 rad forward over S seconds from the upright posture and stays there (``moveheld-S``
holding a 3 kg object in the right hand from the first point); ``planner-NAME`` runs the real planner on the
built-in scenario NAME; ``error``
raises; ``infeasible`` returns an infeasible plan; ``quick`` returns at once.
"""

from __future__ import annotations

import hashlib
import os
import signal
import time
from typing import Any

from planner.errors import Canceled


def _spin(seconds: float, ctx: Any, poll: bool) -> int:
    end = time.monotonic() + seconds
    start = time.monotonic()
    digest = b"seed"
    n = 0
    while time.monotonic() < end:
        for _ in range(200):
            digest = hashlib.sha256(digest).digest()
        n += 1
        if poll:
            if ctx.cancelled():
                raise Canceled("canceled while busy")
            ctx.progress(min(1.0, (time.monotonic() - start) / max(seconds, 1e-9)), f"busy {n}")
    return n


def _plan_doc(request: dict[str, Any], **extra: Any) -> dict[str, Any]:
    return {"schema": "test/1", "status": "solved", "failure": None, "seed": request.get("seed") or 0,
            "request": request, **extra}


def run(request: dict[str, Any], ctx: Any) -> dict[str, Any]:
    name = request["scenario"] if isinstance(request["scenario"], str) else "quick"
    mode, _, arg = name.partition("-")
    if mode == "busy":
        n = _spin(float(arg or 1.0), ctx, poll=True)
        return _plan_doc(request, iterations=n)
    if mode == "hang":
        n = _spin(float(arg or 30.0), ctx, poll=False)
        return _plan_doc(request, iterations=n)
    if mode == "crash":
        ctx.progress(0.1, "about to crash")
        time.sleep(0.2)
        os.kill(os.getpid(), signal.SIGKILL)
    if mode == "exit":
        ctx.progress(0.1, "about to exit")
        time.sleep(0.2)
        os._exit(int(arg or 7))
    if mode == "robot":
        return _plan_doc(request, **robot_loads())
    if mode == "stand":
        return stand(request, ctx, float(arg or STAND_DURATION_S))
    if mode in ("move", "moveheld"):
        import sys
        from pathlib import Path

        sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
        from bridge.plans import build_plan

        ctx.progress(0.5, "moving plan")
        holding = {"holding": "right", "mass_kg": 3.0} if mode == "moveheld" else {}
        return build_plan({"RSP": -0.5}, duration_s=float(arg or 4.0), rest_s=0.05, **holding)
    if mode == "standbad":
        return stand(request, ctx, float(arg or STAND_DURATION_S), bad_joint=True)
    if mode == "planner":  # the real planner on the built-in scenario named after the dash
        from planner.jobs.entry import run_plan

        return run_plan({**request, "scenario": arg}, ctx)
    if mode == "error":
        raise RuntimeError("the test handler failed on purpose")
    if mode == "infeasible":
        return {"schema": "test/1", "status": "infeasible",
                "failure": {"code": "COM_MARGIN", "message": "no plan keeps the margin", "counts": {}}}
    ctx.progress(1.0, "quick")
    return _plan_doc(request)


def robot_loads() -> dict[str, Any]:
    """This worker process's pid and how often it has really loaded a robot model.

    ``load_robot`` is cached per process: a miss is a real load (URDF parse, model
    build). A worker that preloaded its robot and then runs this handler shows one
    miss and at least one hit (the call below) however many jobs it has run.
    """
    from planner.robot.model import load_robot

    load_robot("hrp5p")
    info = load_robot.cache_info()
    return {"pid": os.getpid(), "robot_loads": info.misses, "robot_cache_hits": info.hits}


HANDLERS = {"plan": "svc_test_handlers:run", "survey": "svc_test_handlers:run", "recover": "planner.jobs.entry:run_recover"}


#: Length of the standing-still plan made by :func:`stand`, s.
STAND_DURATION_S = 1.0


def stand(request: dict[str, Any], ctx: Any, duration_s: float = STAND_DURATION_S,
          bad_joint: bool = False) -> dict[str, Any]:
    """A real, gate-valid plan that holds the upright stance posture still (for dispatch tests).

    ``bad_joint`` puts one joint past its URDF limit from the middle on: the gate must veto it.
    """
    from planner.robot.model import load_robot
    from planner.stability.robot_com import robot_com as center_of_mass
    from planner.robot.registry import urdf_sha256
    from planner.stability.stances import solve_stance

    robot = load_robot("hrp5p")
    stance = solve_stance(robot, "upright")
    data = robot.create_data()
    com = [float(v) for v in center_of_mass(robot, data, stance.base_pose, stance.q)]
    margin = float(stance.polygon.margin_one(com[0], com[1]))
    dt = 0.005
    n = int(round(duration_s / dt)) + 1
    pose = [0.5, -0.3, 0.9, 0.0, 0.0, 0.0, 1.0]
    q = [float(v) for v in stance.q]
    ctx.progress(0.5, "standing")
    trajectory = [{"t": i * dt, "q": q, "holding": "none", "object_pose": pose, "com": com, "margin_m": margin,
                   "zmp": com[:2]} for i in range(n)]
    if bad_joint:
        q_bad = list(q)
        q_bad[0] = float(robot.upper[0]) + 0.5
        for point in trajectory[n // 2:]:
            point["q"] = q_bad
    return {
        "schema": "regrasp.plan/1", "status": "solved", "failure": None,
        "robot": {"name": "hrp5p", "urdf_sha256": urdf_sha256("hrp5p"), "joint_names": list(robot.joint_names)},
        "scenario": {"name": "stand"}, "stance": stance.result().model_dump(mode="json"),
        "support_polygon": stance.polygon.vertices.tolist(),
        "object": {"name": "box", "mass_kg": 1.0, "com_local": [0.0, 0.0, 0.0], "start_pose": pose, "goal_pose": pose},
        "threshold_m": float(request.get("threshold_m", 0.03)), "hands": "right-right", "dt_s": dt,
        "trajectory": trajectory,
        "segments": [{"kind": "transit", "hand": "none", "first": 0, "last": n - 1}],
        "min_margin_m": margin, "alternatives": [], "stats": {"test": "stand"},
    }
