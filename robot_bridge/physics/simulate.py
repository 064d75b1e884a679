"""``regrasp simulate``: play a plan in the twin and report what the feet felt (CONTRACT 9, regrasp.simreport/1).

The twin stands in the plan's first posture for ``settle_s`` (plan time starts after it), then the plan's samples
are commanded at its ``dt_s`` (the control period), ``speed`` times faster when asked (a stress test: the plan's
time advances ``speed`` x ``dt_s`` per control period, postures interpolated), then the last posture is held for
``settle_s`` more. The first fault ends the run, as it ends a job on the controller. The held object's weight is brought onto the hand over ``load_ramp_s`` where the plan grasps,
at the CoM the plan's object pose gives. Deterministic: the same plan and settings give the same report but
``wall_s``.

:func:`hold` stands the twin still in one of the plan's postures instead: what the feet feel there with no motion.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from schemas.plan import plan_sha256

from ..errors import BridgeError
from ..plant import PlantFault
from ..robot_files import RobotFilesError, robot_files
from .model import SIDES, TwinModelError, build_twin_model
from .settings import TwinSettings
from .twin import Twin

SIMREPORT_SCHEMA = "regrasp.simreport/1"
#: Columns of samples.csv, in order (CONTRACT 9).
SAMPLE_COLUMNS = ("t", "plan_margin_m", "plan_zmp_x", "plan_zmp_y", "cop_x", "cop_y", "cop_margin_m", "com_x",
                  "com_y", "com_z", "force_left_n", "force_right_n", "base_tilt_rad")
HOLDINGS = ("none", "left", "right", "both")
#: How long :func:`hold` stands the twin still before its window (s): long enough for the CoP's dip from a load held
#: at the window's start, which comes onto the hand during it, to die out (docs/physics.md).
HOLD_SETTLE_S = 5.0


class SimulateInputError(BridgeError, ValueError):
    """A plan the twin cannot play (one line saying what is wrong)."""


@dataclass
class SimResult:
    """The report (CONTRACT 9) and the per-sample rows (SAMPLE_COLUMNS order)."""

    report: dict[str, Any]
    samples: list[tuple[float, ...]]
    polygon: np.ndarray
    #: the held load the wrist sensors read while the payload check judged it, over the planned weight
    #: (smallest, largest); None when it never judged
    held_load_ratio: tuple[float, float] | None = None

    @property
    def stood(self) -> bool:
        return self.report["fault"] is None


def _quat_matrix(xyzw: np.ndarray) -> np.ndarray:
    x, y, z, w = np.asarray(xyzw, dtype=float) / np.linalg.norm(xyzw)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _check_plan(plan: Any) -> None:
    if not isinstance(plan, dict) or plan.get("schema") != "regrasp.plan/1":
        raise SimulateInputError("not a regrasp.plan/1 document")
    if plan.get("status") != "solved":
        raise SimulateInputError(f"the plan is {plan.get('status')!r}, not solved: nothing to simulate")
    try:
        names = plan["robot"]["joint_names"]
        traj = plan["trajectory"]
        dt = float(plan["dt_s"])
        base = np.array(plan["stance"]["base_pose"], dtype=float)
        q = np.array([p["q"] for p in traj], dtype=float)
        for p in traj:
            if p["holding"] not in HOLDINGS:
                raise SimulateInputError(f"holding {p['holding']!r} is not one of {', '.join(HOLDINGS)}")
        poses = np.array([p["object_pose"] for p in traj], dtype=float)
        mass = float(plan["object"]["mass_kg"])
        com_local = np.array(plan["object"]["com_local"], dtype=float)
        float(plan["min_margin_m"])
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        if isinstance(exc, SimulateInputError):
            raise
        raise SimulateInputError(f"malformed plan: {type(exc).__name__} {exc}") from None
    if not traj or q.ndim != 2 or q.shape[1] != len(names):
        raise SimulateInputError("the trajectory's postures do not match robot.joint_names")
    if base.shape != (7,) or poses.shape != (len(traj), 7) or com_local.shape != (3,):
        raise SimulateInputError("stance.base_pose, object_pose and com_local must be [7], [7] and [3] numbers")
    for what, arr in (("dt_s", np.array([dt])), ("q", q), ("base_pose", base), ("object_pose", poses),
                      ("object mass", np.array([mass])), ("com_local", com_local)):
        if not np.all(np.isfinite(arr)):
            raise SimulateInputError(f"the plan's {what} holds a non-finite value")
    if dt <= 0 or dt > 0.1 or abs(dt / 0.001 - round(dt / 0.001)) > 1e-6:
        raise SimulateInputError(f"dt_s {dt} must be a positive multiple of the 1 ms physics step, at most 0.1 s")
    if mass < 0:
        raise SimulateInputError(f"the object's mass {mass} kg is negative")


def simulate(plan: dict[str, Any], settings: TwinSettings | None = None, speed: float = 1.0) -> SimResult:
    """Play ``plan`` in the twin; raises SimulateInputError on a plan it cannot play."""
    settings = settings or TwinSettings()
    if not (math.isfinite(speed) and 0 < speed <= 20):
        raise SimulateInputError(f"speed {speed} must be in (0, 20]")
    _check_plan(plan)
    started = time.perf_counter()
    traj = plan["trajectory"]
    q = np.array([p["q"] for p in traj], dtype=float)
    dt = float(plan["dt_s"])
    twin = _twin(plan, settings, q[0])
    twin.t = -settings.settle_s
    holding = traj[0]["holding"]
    _grasp(twin, plan, 0, "none", holding, q[0])
    for _ in range(int(round(settings.settle_s / dt))):
        if twin.control(q[0], holding, dt) is not None:
            break
    if twin.fault is None:
        twin.extremes = type(twin.extremes)()  # the plan's figures start with the plan
    twin.t = 0.0
    duration = (len(traj) - 1) * dt
    rows: list[tuple[float, ...]] = []
    steps = int(math.ceil(duration / (dt * speed) - 1e-9))
    for k in range(steps + 1 if twin.fault is None else 0):
        tau = min(k * dt * speed, duration)
        f = tau / dt
        i = min(int(math.floor(f + 1e-9)), len(traj) - 1)
        qk = q[i] if i + 1 >= len(traj) else q[i] + (f - i) * (q[i + 1] - q[i])
        new = traj[i]["holding"]
        if new != holding:
            _grasp(twin, plan, i, holding, new, qk)
            holding = new
        fault = twin.control(qk, holding, dt)
        ms = twin.last
        p = traj[i]
        rows.append((tau, float(p["margin_m"]), float(p["zmp"][0]), float(p["zmp"][1]), float(ms.cop[0]),
                     float(ms.cop[1]), ms.cop_margin_m, *map(float, ms.com), ms.foot_forces_n["left"],
                     ms.foot_forces_n["right"], ms.base_tilt_rad))
        if fault is not None:
            break  # the controller ends the job at its first fault: the figures are the motion's up to it
    for _ in range(int(round(settings.settle_s / dt)) if twin.fault is None else 0):
        if twin.control(q[-1], holding, dt) is not None:
            break
    report = _report(plan, twin, settings, speed, time.perf_counter() - started)
    return SimResult(report=report, samples=rows, polygon=twin.polygon.vertices.copy(),
                     held_load_ratio=twin.extremes.held_load_ratio)


@dataclass
class HoldResult:
    """The twin standing still in one posture of a plan (:func:`hold`); margins in m, inside positive."""

    at_s: float
    holding: str
    plan_margin_m: float  # the plan's static CoM margin at that sample
    min_cop_margin_m: float  # the smallest CoP margin from the window's start (settled) to the end
    settled_cop_margin_m: float  # the CoP margin at the end
    fault: PlantFault | None


def hold(plan: dict[str, Any], index: int, settings: TwinSettings | None = None, seconds: float = 3.0,
         window_s: float = 1.0, settle_s: float = HOLD_SETTLE_S) -> HoldResult:
    """The twin standing still in the plan's posture at sample ``index`` while what the hands hold changes as it did
    in the plan over the ``window_s`` before that sample: it settles for ``settle_s`` holding what the hands held at
    the window's start, the holding changes come at their times (each load ramped as in a run), and it stands
    ``seconds`` more. What the feet feel with no motion at all: the part of a run's smallest CoP margin that no
    timing of the motion can take away.

    The settle is longer than a run's (``settings.settle_s``): a load held at the window's start comes onto the hand
    during the settle, and the CoP's dip from it lasts seconds (the stabilizer's integral leaks over
    ``cop_leak_s``); cut short, that dip would be counted as the window's. Raises SimulateInputError on a plan it
    cannot play or a bad argument."""
    settings = settings or TwinSettings()
    _check_plan(plan)
    traj = plan["trajectory"]
    if not 0 <= index < len(traj):
        raise SimulateInputError(f"sample {index} is not in the plan's {len(traj)} samples")
    if not (math.isfinite(seconds) and 0 < seconds <= 60 and math.isfinite(window_s) and 0 <= window_s <= 10
            and math.isfinite(settle_s) and 0 <= settle_s <= 60):
        raise SimulateInputError(f"seconds {seconds} must be in (0, 60], window_s {window_s} in [0, 10] and "
                                 f"settle_s {settle_s} in [0, 60]")
    q = np.array(traj[index]["q"], dtype=float)
    dt = float(plan["dt_s"])
    first = max(0, index - int(round(window_s / dt)))
    twin = _twin(plan, settings, q)
    holding = traj[first]["holding"]
    _grasp(twin, plan, index, "none", holding, q)  # the object where the plan has it at the held sample
    for _ in range(int(round(settle_s / dt))):
        twin.control(q, holding, dt)
    twin.extremes = type(twin.extremes)()
    for i in [*range(first + 1, index + 1), *[index] * int(round(seconds / dt))]:
        new = traj[i]["holding"]
        if new != holding:
            _grasp(twin, plan, index, holding, new, q)
            holding = new
        if twin.control(q, holding, dt) is not None:
            break
    return HoldResult(at_s=float(traj[index]["t"]), holding=holding, plan_margin_m=float(traj[index]["margin_m"]),
                      min_cop_margin_m=float(twin.extremes.min_cop_margin_m),
                      settled_cop_margin_m=float(twin.last.cop_margin_m), fault=twin.fault)


def _twin(plan: dict[str, Any], settings: TwinSettings, q0: np.ndarray) -> Twin:
    """A twin of the plan's robot in its stance, standing in posture ``q0``, told the plan's object mass."""
    robot = plan["robot"]
    try:
        files = robot_files(robot["name"], robot.get("urdf_sha256"))
        tm = build_twin_model(files.urdf, files.spec, list(robot["joint_names"]), settings)
    except (RobotFilesError, TwinModelError) as exc:
        raise SimulateInputError(str(exc)) from None
    frame_side = {files.spec["feet"][s]["frame"]: s for s in SIDES}
    in_contact = {frame_side[f["frame"]]: bool(f.get("in_contact", True)) for f in plan["stance"]["feet"]
                  if f.get("frame") in frame_side}
    return Twin(tm, np.array(plan["stance"]["base_pose"]), q0, in_contact, settings,
                object_mass_kg=float(plan["object"]["mass_kg"]))


def _grasp(twin: Twin, plan: dict[str, Any], i: int, old: str, new: str, q_cmd: np.ndarray) -> None:
    """Where a hand closes on the object at sample ``i``, fix its CoM in that hand's TCP frame."""
    sides = {"none": (), "left": ("left",), "right": ("right",), "both": ("left", "right")}
    closing = [s for s in sides[new] if s not in sides[old]]
    if not closing:
        return
    pose = np.array(plan["trajectory"][i]["object_pose"], dtype=float)
    com_world = pose[:3] + _quat_matrix(pose[3:]) @ np.array(plan["object"]["com_local"], dtype=float)
    twin.set_reference(q_cmd)
    for side in closing:
        twin.grasp(side, com_world)


def _finite_or_none(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _report(plan: dict[str, Any], twin: Twin, settings: TwinSettings, speed: float, wall_s: float) -> dict[str, Any]:
    ex, fault = twin.extremes, twin.fault
    fell = fault is not None and fault.kind == "fall"
    min_margin = _finite_or_none(ex.min_cop_margin_m)
    plan_min = float(plan["min_margin_m"])
    return {
        "schema": SIMREPORT_SCHEMA,
        "plan_sha256": plan_sha256(plan),
        "robot": plan["robot"],
        "engine": {"name": "mujoco", "version": mujoco.__version__, "timestep_s": settings.timestep_s},
        "stabilizer": settings.stabilizer.enabled,
        "speed": float(speed),
        "mass_scale": settings.mass_scale,
        "fell": fell,
        "fell_at_s": fault.at_s if fell else None,
        "fault": None if fault is None else {"kind": fault.kind, "at_s": fault.at_s, "detail": fault.detail},
        "min_cop_margin_m": min_margin,
        "min_cop_margin_at_s": ex.min_cop_margin_at_s if min_margin is not None else None,
        "cop_margin_ratio": None if min_margin is None or plan_min <= 0 else min_margin / plan_min,
        "max_tracking_error_rad": ex.max_tracking_error_rad,
        "max_torque_ratio": ex.max_torque_ratio,
        "foot_slip_m": ex.foot_slip_m,
        "foot_tilt_rad": ex.foot_tilt_rad,
        "wall_s": wall_s,
    }
