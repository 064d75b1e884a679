"""Reading a plan document into the gate's arrays, naming the first malformed value.

The plan arrives as canonical JSON bytes; :func:`loads_plan` parses them with orjson
(json.loads's results, several times faster on a 10 MB plan). The bytes the plan's hash
covers are hashed as they are, never written again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import chain
from operator import itemgetter
from typing import Any

import numpy as np

from schemas.fast_json import loads
from schemas.plan import PLAN_SCHEMA

from .gate_context import _Context
from .gate_types import _HOLDING, GateSettings, Veto


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number the plan may hold")


def loads_plan(raw: bytes) -> Any:
    """The plan JSON parsed (NaN and Infinity refused with json.loads's ValueError)."""
    return loads(raw, parse_constant=_reject_constant)


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
        # (~8 ms for 12k points; an exact type test costs ~30 ms). JSON true/false read as 1/0, like Python.
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
    return _Parsed(
        robot_name=str(name), urdf_sha256=str(robot.get("urdf_sha256", "")), joint_names=tuple(names), n=len(traj),
        dt=float(dt), t=t, Q=Q, holding=holding, object_pose=poses, base_pose=base, feet=clean_feet,
        mass=float(mass), com_local=com_local, threshold=float(thr), moving=np.flatnonzero(np.any(Q != Q[:1], axis=0)),
    )
