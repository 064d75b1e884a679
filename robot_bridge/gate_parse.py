"""Reading a plan document into the gate's arrays, naming the first malformed value.

The plan arrives as canonical JSON bytes. :func:`decode_executable` reads them straight into
typed structures (msgspec) holding only the fields the gate checks, the values' JSON types
checked while decoding; that is the fast path, and the structures it returns are what the
dispatcher cuts into segments, so what is executed is exactly what was checked. Anything the
typed reading does not take as it is (a wrong type, a missing field, NaN, a value out of range)
goes the slow way: :func:`loads_plan` (orjson, with json.loads's results) and :func:`_parse`,
whose veto names the first malformed value. The bytes the plan's hash covers are hashed as they
are, never written again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import chain
from operator import attrgetter, itemgetter
from typing import Any

import msgspec
import numpy as np

from schemas.fast_json import collector_paused, loads
from schemas.plan import PLAN_SCHEMA

from .gate_context import _Context
from .gate_types import _HOLDING, GateSettings, Veto


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number the plan may hold")


def loads_plan(raw: bytes) -> Any:
    """The plan JSON parsed (NaN and Infinity refused with json.loads's ValueError)."""
    return loads(raw, parse_constant=_reject_constant)


class PointIn(msgspec.Struct, gc=False):
    """One trajectory point as the gate reads it (other fields of the point are skipped)."""

    t: float
    q: list[float]
    holding: str
    object_pose: list[float]


class FootIn(msgspec.Struct, gc=False):
    frame: str
    pose: list[float]
    in_contact: bool = True


class StanceIn(msgspec.Struct, gc=False):
    base_pose: list[float]
    feet: list[FootIn]


class RobotIn(msgspec.Struct, gc=False):
    name: str
    joint_names: list[str]
    urdf_sha256: str = ""


class ObjectIn(msgspec.Struct, gc=False):
    mass_kg: float
    com_local: list[float]


class TimingIn(msgspec.Struct, gc=False):
    speed_scale: float | None = None


class ExecutablePlan(msgspec.Struct, gc=False):
    """The fields of a plan document (schemas.plan) that the gate checks and the dispatcher sends."""

    schema: str
    status: str
    robot: RobotIn
    stance: StanceIn
    object: ObjectIn
    threshold_m: float
    dt_s: float
    trajectory: list[PointIn]
    timing: TimingIn | None = None


_EXECUTABLE = msgspec.json.Decoder(ExecutablePlan)


def decode_executable(raw: bytes) -> ExecutablePlan | None:
    """The plan's checked fields read from its JSON bytes, or None when they are not all of their JSON
    types (then :func:`loads_plan` and :func:`_parse` read the plan and name what is wrong)."""
    try:
        with collector_paused(len(raw)):  # as schemas.fast_json does for a document (its docstring says why)
            return _EXECUTABLE.decode(raw)
    except (msgspec.ValidationError, msgspec.DecodeError):
        return None


@dataclass
class _Parsed:
    robot_name: str
    urdf_sha256: str
    joint_names: tuple[str, ...]
    n: int
    dt: float
    t: np.ndarray
    Q: np.ndarray
    holding: np.ndarray  # (n,) int index into _HOLDING
    object_pose: np.ndarray  # (n, 7)
    base_pose: np.ndarray
    feet: list[dict]
    mass: float
    com_local: np.ndarray
    threshold: float
    moving: np.ndarray  # columns of Q that change at some point (plans move a few joints at a time)
    speed_scale: float | None = None  # the plan's timing.speed_scale, when it has one


def _get(doc: Any, key: str, what: str) -> Any:
    if not isinstance(doc, dict) or key not in doc:
        raise Veto("structure", f"the plan lacks {what}")
    return doc[key]


def _floats(values: Any, length: int, what: str) -> np.ndarray:
    try:
        arr = np.array(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise Veto("structure", f"{what} is not a list of numbers: {exc}") from exc
    if arr.shape != (length,):
        raise Veto("structure", f"{what} must have {length} numbers, got shape {arr.shape}")
    return arr


def _find_bad_point(traj: list, nq: int) -> None:
    """Raise a veto naming the first malformed trajectory point."""
    for i, pt in enumerate(traj):
        if not isinstance(pt, dict):
            raise Veto("structure", f"trajectory[{i}] is not an object")
        for key in ("t", "q", "holding", "object_pose"):
            if key not in pt:
                raise Veto("structure", f"trajectory[{i}] lacks {key!r}")
        if not isinstance(pt["q"], list) or len(pt["q"]) != nq:
            raise Veto("structure", f"trajectory[{i}].q must have {nq} values (robot.joint_names)")
        if not isinstance(pt["object_pose"], list) or len(pt["object_pose"]) != 7:
            raise Veto("structure", f"trajectory[{i}].object_pose must have 7 values")
        if pt["holding"] not in _HOLDING:
            raise Veto("structure", f"trajectory[{i}].holding is {pt['holding']!r}; one of {_HOLDING}")
        for key, values in (("q", pt["q"]), ("object_pose", pt["object_pose"]), ("t", [pt["t"]])):
            for k, v in enumerate(values):
                if not isinstance(v, (int, float)):  # JSON numbers only: no "1.5", no null
                    where = f"trajectory[{i}].{key}" + (f"[{k}]" if key != "t" else "")
                    raise Veto("structure", f"{where} is {v!r}, not a number")


def _parse(ctx: "_Context", plan: Any, s: GateSettings) -> _Parsed:
    if not isinstance(plan, dict):
        raise Veto("structure", f"a plan is a JSON object, got {type(plan).__name__}")
    if plan.get("schema") != PLAN_SCHEMA:
        raise Veto("structure", f"schema is {plan.get('schema')!r}, expected {PLAN_SCHEMA!r}")
    if plan.get("status") != "solved":
        raise Veto("structure", f"only a solved plan can be executed; status is {plan.get('status')!r}")
    robot = _get(plan, "robot", "robot")
    name = _get(robot, "name", "robot.name")
    names = _get(robot, "joint_names", "robot.joint_names")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise Veto("structure", "robot.joint_names must be a non-empty list of names")
    traj = _get(plan, "trajectory", "trajectory")
    if not isinstance(traj, list) or not traj:
        raise Veto("structure", "the trajectory is empty")
    if len(traj) > s.max_points:
        raise Veto("structure", f"the trajectory has {len(traj)} points; at most {s.max_points} are accepted")
    dt = _get(plan, "dt_s", "dt_s")
    if not isinstance(dt, (int, float)) or not math.isfinite(dt) or dt <= 0 or dt > 1.0:
        raise Veto("structure", f"dt_s is {dt!r}; it must be a finite period in (0, 1] s")
    nq = len(names)
    index = {h: k for k, h in enumerate(_HOLDING)}
    try:  # the fast path: whole columns at once; the slow path below only names what is wrong
        n = len(traj)
        qs, ps = list(map(itemgetter("q"), traj)), list(map(itemgetter("object_pose"), traj))
        if set(map(type, qs)) != {list} or set(map(type, ps)) != {list} or set(map(len, qs)) != {nq} \
                or set(map(len, ps)) != {7}:
            raise ValueError("shape")
        # np.fromiter would read the string "1.5" as a number; sum() raises TypeError on a string or a null
        # (cheaper than an exact type test per value). JSON true/false read as 1/0, like Python.
        sum(chain(chain.from_iterable(qs), chain.from_iterable(ps), map(itemgetter("t"), traj)))
        Q = np.fromiter(chain.from_iterable(qs), dtype=float, count=n * nq).reshape(n, nq)
        t = np.fromiter(map(itemgetter("t"), traj), dtype=float, count=n)
        poses = np.fromiter(chain.from_iterable(ps), dtype=float, count=n * 7).reshape(n, 7)
        holding = np.fromiter(map(index.__getitem__, map(itemgetter("holding"), traj)), dtype=np.int8, count=n)
    except (TypeError, ValueError, KeyError):
        _find_bad_point(traj, nq)
        raise Veto("structure", "the trajectory holds a value that is not a number")
    stance = _get(plan, "stance", "stance")
    base = _floats(_get(stance, "base_pose", "stance.base_pose"), 7, "stance.base_pose")
    feet = _get(stance, "feet", "stance.feet")
    if not isinstance(feet, list) or not feet:
        raise Veto("structure", "stance.feet is empty")
    clean_feet = []
    for k, foot in enumerate(feet):
        frame = _get(foot, "frame", f"stance.feet[{k}].frame")
        pose = _floats(_get(foot, "pose", f"stance.feet[{k}].pose"), 7, f"stance.feet[{k}].pose")
        clean_feet.append({"frame": frame, "pose": pose, "in_contact": bool(foot.get("in_contact", True))})
    obj = _get(plan, "object", "object")
    mass = _get(obj, "mass_kg", "object.mass_kg")
    if not isinstance(mass, (int, float)) or not math.isfinite(mass) or mass < 0:
        raise Veto("structure", f"object.mass_kg is {mass!r}; it must be finite and >= 0")
    com_local = _floats(_get(obj, "com_local", "object.com_local"), 3, "object.com_local")
    thr = _get(plan, "threshold_m", "threshold_m")
    if not isinstance(thr, (int, float)):
        raise Veto("structure", f"threshold_m is {thr!r}")
    timing = plan.get("timing")
    speed = timing.get("speed_scale") if isinstance(timing, dict) else None
    if timing is not None and not isinstance(timing, dict):
        raise Veto("structure", f"timing is {type(timing).__name__}; it must be an object")
    if speed is not None and (isinstance(speed, bool) or not isinstance(speed, (int, float)) or not math.isfinite(speed)
                              or speed <= 0):
        raise Veto("structure", f"timing.speed_scale is {speed!r}; it must be a finite number > 0")
    return _Parsed(
        robot_name=str(name), urdf_sha256=str(robot.get("urdf_sha256", "")), joint_names=tuple(names), n=len(traj),
        dt=float(dt), t=t, Q=Q, holding=holding, object_pose=poses, base_pose=base, feet=clean_feet,
        mass=float(mass), com_local=com_local, threshold=float(thr), moving=np.flatnonzero(np.any(Q != Q[:1], axis=0)),
        speed_scale=None if speed is None else float(speed),
    )


def _parse_executable(plan: ExecutablePlan, s: GateSettings) -> _Parsed | None:
    """:func:`_parse` on typed structures, when every value is as it must be; else None (the caller then
    parses the plan as a document, and that path names the first malformed value)."""
    traj, names = plan.trajectory, plan.robot.joint_names
    dt, mass = plan.dt_s, plan.object.mass_kg
    if (plan.schema != PLAN_SCHEMA or plan.status != "solved" or not names or not traj or len(traj) > s.max_points
            or not (math.isfinite(dt) and 0 < dt <= 1.0) or not (math.isfinite(mass) and mass >= 0)
            or len(plan.stance.base_pose) != 7 or not plan.stance.feet or len(plan.object.com_local) != 3
            or any(len(f.pose) != 7 for f in plan.stance.feet)):
        return None
    speed = plan.timing.speed_scale if plan.timing is not None else None
    if speed is not None and not (math.isfinite(speed) and speed > 0):
        return None
    n, nq = len(traj), len(names)
    qs, ps = list(map(attrgetter("q"), traj)), list(map(attrgetter("object_pose"), traj))
    if set(map(len, qs)) != {nq} or set(map(len, ps)) != {7}:
        return None
    index = {h: k for k, h in enumerate(_HOLDING)}
    try:
        holding = np.fromiter(map(index.__getitem__, map(attrgetter("holding"), traj)), dtype=np.int8, count=n)
    except KeyError:
        return None
    Q = np.fromiter(chain.from_iterable(qs), dtype=float, count=n * nq).reshape(n, nq)
    return _Parsed(
        robot_name=plan.robot.name, urdf_sha256=plan.robot.urdf_sha256, joint_names=tuple(names), n=n, dt=float(dt),
        t=np.fromiter(map(attrgetter("t"), traj), dtype=float, count=n), Q=Q, holding=holding,
        object_pose=np.fromiter(chain.from_iterable(ps), dtype=float, count=n * 7).reshape(n, 7),
        base_pose=np.array(plan.stance.base_pose, dtype=float),
        feet=[{"frame": f.frame, "pose": np.array(f.pose, dtype=float), "in_contact": f.in_contact} for f in plan.stance.feet],
        mass=float(mass), com_local=np.array(plan.object.com_local, dtype=float), threshold=float(plan.threshold_m),
        moving=np.flatnonzero(np.any(Q != Q[:1], axis=0)), speed_scale=speed,
    )
