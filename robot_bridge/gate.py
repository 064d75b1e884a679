"""The safety gate: an independent recheck of a plan just before it reaches the robot.

Its own code path (URDF parsed here, kinematics in :mod:`robot_bridge.urdf_kinematics`,
support polygon in :mod:`robot_bridge.support`); it never imports the planner or
pinocchio, and it never trusts the CoM, margin or ZMP numbers written in the plan.
It checks every sample at the controller period (plus midpoints, since the
controller interpolates linearly between points), not only the plan's knots,
with exact kinematics at every one of them.

It fails closed: any exception becomes a veto (check ``gate_error``). A veto names
the check and the first failing sample; the dispatcher sends nothing after one.

This gate is operational risk reduction on top of the controller's own limiters
and the hardware e-stop. It is not a safety-rated function.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from itertools import chain
from operator import itemgetter
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from schemas.bridge import GateVerdict
from schemas.plan import PLAN_SCHEMA, plan_sha256

from .robot_files import RobotFiles, robot_files
from .support import Polygon, support_polygon
from .gate_effort import EffortVeto, check_effort_and_grip
from .urdf_kinematics import BatchFK, UrdfModel, load_urdf

_HOLDING = ("none", "left", "right", "both")


class GateSettings(BaseModel):
    """Tolerances and sampling of the gate; defaults follow CONTRACT.md section 3."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    controller_period_s: float = Field(0.005, gt=0, description="the controller's interpolation period (200 Hz)")
    oversample: int = Field(2, ge=1, le=16, description="samples per controller period (2: the midpoints too)")
    margin_tolerance_m: float = Field(1e-4, ge=0, description="the contract's tolerance on the CoM margin")
    zmp_tolerance_m: float = Field(1e-4, ge=0, description="how far outside the polygon a ZMP may be (rounding)")
    start_tolerance_rad: float = Field(0.01, gt=0, description="first point vs the measured state, per joint")
    feet_tolerance_m: float = Field(1e-3, gt=0, description="soles vs the stance's foot placements")
    position_tolerance: float = Field(1e-9, ge=0, description="slack on the URDF position limits (rad or m)")
    limit_tolerance_rel: float = Field(1e-6, ge=0, description="relative slack on velocity/acceleration limits")
    time_tolerance_s: float = Field(1e-6, ge=0, description="|t_i - i dt_s| allowed")
    gravity: float = Field(9.81, gt=0)
    check_limits: bool = Field(True, description="check static joint torques and grip against the robot's limits")
    max_points: int = Field(720_000, gt=0, description="largest trajectory accepted (1 h at 200 Hz)")


@dataclass(frozen=True)
class Approval:
    """What an approver signed: the plan's SHA-256, valid until ``expires_at``."""

    sha256: str
    expires_at: datetime


@dataclass(frozen=True)
class MeasuredState:
    """The robot's measured joint positions, by name (from ``state/joints``)."""

    joint_names: Sequence[str]
    q: Sequence[float]
    tolerance_rad: float | None = None


class Veto(Exception):
    """Raised inside the gate to stop at the first failing check."""

    def __init__(self, check: str, message: str, sample_index: int | None = None):
        super().__init__(message)
        self.check = check
        self.message = message
        self.sample_index = sample_index


@dataclass(frozen=True)
class _Robot:
    files: RobotFiles
    model: UrdfModel
    urdf_sha256: str


class SafetyGate:
    """Checks plans for one process; robot models are parsed once and cached."""

    def __init__(self, settings: GateSettings | None = None):
        self.settings = settings or GateSettings()
        self._robots: dict[str, _Robot] = {}
        self._fk: dict[tuple[str, tuple[str, ...]], BatchFK] = {}

    # ------------------------------------------------------------------ public
    def check(
        self,
        plan: dict[str, Any],
        *,
        approval: Approval | None = None,
        measured: MeasuredState | None = None,
        threshold_m: float | None = None,
        now: datetime | None = None,
        offline: bool = False,
    ) -> GateVerdict:
        """The verdict on ``plan``. Online (the default) an approval and a measured state are required.

        ``offline`` skips the approval, hash and start-state checks when they are not
        given (``regrasp gate check``); every other check runs the same way.
        """
        return self._check(plan, None, approval, measured, threshold_m, now, offline)

    def check_json(self, plan_json: bytes | str, **kwargs: Any) -> tuple[GateVerdict, dict[str, Any] | None]:
        """Check a plan given as its canonical JSON bytes; returns the verdict and the parsed plan.

        The fast path for large plans: the SHA-256 is taken over the bytes as they are
        (milliseconds) instead of re-serialising the plan (about a second for a 60 s
        plan). Sound because equal hashes mean equal bytes: bytes that are not the
        approved canonical JSON fail the hash check. Keyword arguments as :meth:`check`.
        """
        raw = plan_json.encode() if isinstance(plan_json, str) else bytes(plan_json)
        t0 = time.perf_counter()
        digest = hashlib.sha256(raw).hexdigest()
        t1 = time.perf_counter()
        try:
            plan = json.loads(raw, parse_constant=_reject_constant)
        except (ValueError, RecursionError) as exc:
            ctx = _Context(settings=self.settings)
            return ctx.verdict(False, "structure", f"the plan is not valid JSON: {exc}", None, time.perf_counter() - t0), None
        verdict = self._check(plan, (digest, t1 - t0), kwargs.pop("approval", None), kwargs.pop("measured", None),
                              kwargs.pop("threshold_m", None), kwargs.pop("now", None), kwargs.pop("offline", False),
                              json_s=time.perf_counter() - t1, **kwargs)
        return verdict, plan

    def _check(self, plan: Any, digest: tuple[str, float] | None, approval: Approval | None, measured: MeasuredState | None,
               threshold_m: float | None, now: datetime | None, offline: bool, json_s: float | None = None) -> GateVerdict:
        started = time.perf_counter()
        ctx = _Context(settings=self.settings)
        ctx.digest = digest
        if json_s is not None:  # check_json: reading the bytes into a plan, before the checks (not in elapsed_s)
            ctx.note("timing", json_s=json_s)
        try:
            self._run(ctx, plan, approval, measured, threshold_m, now, offline)
        except Veto as veto:
            return ctx.verdict(False, veto.check, veto.message, veto.sample_index, time.perf_counter() - started)
        except Exception as exc:  # fail closed: the gate's own failure is a veto
            return ctx.verdict(False, "gate_error", f"the gate could not check the plan: {type(exc).__name__}: {exc}", None,
                               time.perf_counter() - started)
        return ctx.verdict(True, None, "every check passed", None, time.perf_counter() - started)

    # ------------------------------------------------------------------ internals
    def _robot(self, name: str) -> _Robot:
        if name not in self._robots:
            files = robot_files(name)
            self._robots[name] = _Robot(files=files, model=load_urdf(str(files.urdf)), urdf_sha256=files.urdf_sha256)
        return self._robots[name]

    def _batch_fk(self, robot: _Robot, joint_names: tuple[str, ...]) -> BatchFK:
        key = (robot.files.name, joint_names)
        if key not in self._fk:
            self._fk[key] = BatchFK(robot.model, joint_names)
        return self._fk[key]

    def _run(self, ctx: "_Context", plan: dict, approval: Approval | None, measured: MeasuredState | None,
             threshold_m: float | None, now: datetime | None, offline: bool) -> None:
        s = self.settings
        p = _timed(ctx, "parse_s", _parse, ctx, plan, s)
        robot = self._robot(p.robot_name)
        if sorted(p.joint_names) != sorted(robot.model.joint_names) or len(set(p.joint_names)) != len(p.joint_names):
            raise Veto("structure", f"robot.joint_names do not match the URDF of {p.robot_name!r}: unknown "
                       f"{sorted(set(p.joint_names) - set(robot.model.joint_names))}, missing "
                       f"{sorted(set(robot.model.joint_names) - set(p.joint_names))}")
        ctx.passed("structure", points=p.n, joints=len(p.joint_names), dt_s=p.dt)
        ctx.S = max(1, math.ceil(p.dt / s.controller_period_s - 1e-9)) * s.oversample
        ctx.n_points = p.n
        ctx.dt = p.dt
        ctx.samples = (p.n - 1) * ctx.S + 1

        _check_finite(ctx, p)
        ctx.passed("finite")

        thr = p.threshold if threshold_m is None else float(threshold_m)
        if not math.isfinite(thr) or thr < 0:
            raise Veto("structure", f"threshold {thr!r} m must be finite and >= 0")
        ctx.threshold = thr

        if approval is None:
            if not offline:
                raise Veto("approval", "no approval was given; only an approved plan is dispatched")
            ctx.skip("approval", "plan_hash")
            ctx.plan_sha256 = _digest(ctx, plan)
        else:
            when = now or datetime.now(timezone.utc)
            expires = approval.expires_at if approval.expires_at.tzinfo else approval.expires_at.replace(tzinfo=timezone.utc)
            when = when if when.tzinfo else when.replace(tzinfo=timezone.utc)
            if when >= expires:
                raise Veto("approval", f"the approval expired at {expires.isoformat()} (now {when.isoformat()})")
            ctx.passed("approval", expires_at=expires.isoformat())
            digest = _digest(ctx, plan)
            ctx.plan_sha256 = digest
            if digest != approval.sha256:
                raise Veto("plan_hash", f"the plan's SHA-256 {digest} differs from the approved {approval.sha256}: "
                           "the plan was changed after approval")
            ctx.passed("plan_hash", sha256=digest)

        if p.urdf_sha256 != robot.urdf_sha256:
            raise Veto("robot_model", f"the plan was made for URDF {p.urdf_sha256}, the gate loads "
                       f"{robot.urdf_sha256} ({robot.files.urdf}); the kinematics would differ")
        ctx.passed("robot_model", urdf_sha256=robot.urdf_sha256)

        _check_time(ctx, p, s)
        if measured is None:
            if not offline:
                raise Veto("start_state", "the robot's measured state is unknown")
            ctx.skip("start_state")
        else:
            _check_start(ctx, p, measured, s)
        lower, upper = _limits(robot, p)
        _check_position(ctx, p, lower, upper, s)
        _check_rates(ctx, p, robot, s)

        fk = self._batch_fk(robot, p.joint_names)
        polygon = support_polygon(robot.model, p.feet)
        _timed(ctx, "stability_s", _check_stability, ctx, p, fk, polygon, s)
        if s.check_limits:  # static joint torques and grip (robot_bridge.gate_effort)
            try:
                figures = _timed(ctx, "effort_s", check_effort_and_grip, robot.model, robot.files.spec, p.joint_names,
                                 p.Q, p.base_pose, p.holding, p.object_pose, p.com_local, p.mass, p.feet, s.gravity)
                ctx.passed("effort", max_ratio=figures["max_effort_ratio"])
                ctx.passed("grip", max_ratio=figures["max_grip_ratio"])
            except EffortVeto as veto:
                raise Veto(veto.check, veto.message, veto.point * ctx.S) from None


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number the plan may hold")


def _digest(ctx: "_Context", plan: dict) -> str:
    """The plan's SHA-256: over the bytes given to :meth:`SafetyGate.check_json`, else over its canonical JSON."""
    if ctx.digest is not None:
        ctx.note("timing", hash_s=ctx.digest[1])
        return ctx.digest[0]
    return _timed(ctx, "hash_s", plan_sha256, plan)


def _timed(ctx: "_Context", what: str, fn: Any, *args: Any) -> Any:
    """Run ``fn`` and record its wall time under ``stats['timing'][what]``."""
    t0 = time.perf_counter()
    try:
        return fn(*args)
    finally:
        ctx.note("timing", **{what: time.perf_counter() - t0})


# ---------------------------------------------------------------------- parsing


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


# ---------------------------------------------------------------------- checks


@dataclass
class _Context:
    """What the checks found so far; becomes the verdict."""

    settings: GateSettings
    S: int = 1
    n_points: int = 0
    dt: float = 0.0
    samples: int = 0
    threshold: float | None = None
    plan_sha256: str | None = None
    digest: tuple[str, float] | None = None  # (sha256 of the given bytes, seconds it took)

    def __post_init__(self) -> None:
        self.stats: dict[str, dict[str, Any]] = {}
        self.ok: list[str] = []
        self.skipped: list[str] = []

    def passed(self, check: str, **figures: Any) -> None:
        self.ok.append(check)
        if figures:
            self.stats.setdefault(check, {}).update(figures)

    def note(self, check: str, **figures: Any) -> None:
        self.stats.setdefault(check, {}).update(figures)

    def skip(self, *checks: str) -> None:
        self.skipped.extend(checks)

    def verdict(self, passed: bool, check: str | None, message: str, sample: int | None, elapsed: float) -> GateVerdict:
        point = t = None
        if sample is not None and self.S:
            point = min(sample // self.S, max(self.n_points - 1, 0))
            t = sample * self.dt / self.S
        return GateVerdict(
            passed=passed, check=check, sample_index=sample, point_index=point, t=t, message=message,
            plan_sha256=self.plan_sha256, threshold_m=self.threshold, samples=self.samples,
            elapsed_s=elapsed, checks_passed=list(self.ok), skipped=list(self.skipped), stats=_jsonable(self.stats),
        )


def _jsonable(doc: Any) -> Any:
    if isinstance(doc, dict):
        return {k: _jsonable(v) for k, v in doc.items()}
    if isinstance(doc, (list, tuple)):
        return [_jsonable(v) for v in doc]
    if isinstance(doc, (np.floating, float)):
        v = float(doc)
        return v if math.isfinite(v) else None
    if isinstance(doc, np.integer):
        return int(doc)
    return doc


def _first(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def _check_finite(ctx: _Context, p: _Parsed) -> None:
    for what, arr in (("q", p.Q), ("object_pose", p.object_pose), ("t", p.t[:, None])):
        if np.isfinite(arr).all():
            continue
        bad = ~np.isfinite(arr)
        row = _first(bad.any(axis=1))
        if row is not None:
            col = int(np.flatnonzero(bad[row])[0])
            label = f"{what}[{col}] ({p.joint_names[col]})" if what == "q" else f"{what}[{col}]" if what != "t" else "t"
            raise Veto("finite", f"trajectory[{row}].{label} is {arr[row, col]}; every value must be finite", row * ctx.S)
    for k, foot in enumerate(p.feet):
        if not np.all(np.isfinite(foot["pose"])):
            raise Veto("finite", f"stance.feet[{k}].pose is not finite")
    if not (np.all(np.isfinite(p.base_pose)) and np.all(np.isfinite(p.com_local))):
        raise Veto("finite", "stance.base_pose or object.com_local is not finite")
    norms = np.linalg.norm(p.object_pose[:, 3:], axis=1)
    row = _first(np.abs(norms - 1.0) > 1e-3)
    if row is not None:
        raise Veto("finite", f"trajectory[{row}].object_pose has a quaternion of norm {norms[row]:.6f}", row * ctx.S)


def _check_time(ctx: _Context, p: _Parsed, s: GateSettings) -> None:
    if p.n >= 2:
        steps = np.diff(p.t)
        row = _first(steps <= 0.0)
        if row is not None:
            raise Veto("time", f"time does not increase strictly: t[{row + 1}] = {p.t[row + 1]!r} after t[{row}] = {p.t[row]!r}",
                       (row + 1) * ctx.S)
    expected = np.arange(p.n) * p.dt
    off = np.abs(p.t - expected)
    row = _first(off > s.time_tolerance_s + 1e-12 * np.abs(expected))
    if row is not None:
        raise Veto("time", f"t[{row}] = {p.t[row]!r} s, expected {expected[row]!r} s (uniform dt_s = {p.dt})", row * ctx.S)
    ctx.passed("time", duration_s=float(p.t[-1]), dt_s=p.dt, samples_per_point=ctx.S)


def _check_start(ctx: _Context, p: _Parsed, measured: MeasuredState, s: GateSettings) -> None:
    tol = measured.tolerance_rad if measured.tolerance_rad is not None else s.start_tolerance_rad
    index = {n: i for i, n in enumerate(measured.joint_names)}
    missing = [n for n in p.joint_names if n not in index]
    if missing:
        raise Veto("start_state", f"the measured state lacks joints {missing}", 0)
    qm = np.array([measured.q[index[n]] for n in p.joint_names], dtype=float)
    if not np.all(np.isfinite(qm)):
        raise Veto("start_state", "the measured state is not finite", 0)
    dev = np.abs(p.Q[0] - qm)
    worst = int(np.argmax(dev))
    ctx.note("start_state", max_deviation=float(dev[worst]), joint=p.joint_names[worst], tolerance=tol)
    if dev[worst] > tol:
        raise Veto("start_state", f"the first point is {dev[worst]:.4f} from the measured state at joint {p.joint_names[worst]} "
                   f"(plan {p.Q[0, worst]:.4f}, robot {qm[worst]:.4f}; tolerance {tol})", 0)
    ctx.passed("start_state")


def _limits(robot: _Robot, p: _Parsed) -> tuple[np.ndarray, np.ndarray]:
    order = {n: i for i, n in enumerate(robot.model.joint_names)}
    idx = np.array([order[n] for n in p.joint_names])
    return robot.model.lower[idx], robot.model.upper[idx]


def _check_position(ctx: _Context, p: _Parsed, lower: np.ndarray, upper: np.ndarray, s: GateSettings) -> None:
    tol = s.position_tolerance
    qmin, qmax = p.Q.min(axis=0), p.Q.max(axis=0)  # column extremes first: the full mask only on a violation
    ctx.note("joint_position", min_clearance=float(np.min(np.minimum(qmin - lower, upper - qmax))))
    if np.any(qmin < lower - tol) or np.any(qmax > upper + tol):
        bad = (p.Q < lower - tol) | (p.Q > upper + tol)
        row = _first(bad.any(axis=1))
        col = int(np.flatnonzero(bad[row])[0])
        raise Veto("joint_position", f"joint {p.joint_names[col]} at {p.Q[row, col]:.6f} is outside its limits "
                   f"[{lower[col]:.6f}, {upper[col]:.6f}] at point {row}", row * ctx.S)
    ctx.passed("joint_position")


def _check_rates(ctx: _Context, p: _Parsed, robot: _Robot, s: GateSettings) -> None:
    """Velocities and accelerations by finite differences at dt_s; the plan is at rest before and after.

    Only the moving columns are differenced: a joint that holds one value has none.
    """
    cols = p.moving
    if cols.size == 0:  # nothing moves: at rest throughout
        ctx.passed("joint_velocity", max_ratio=0.0)
        ctx.passed("joint_acceleration", max_ratio=0.0)
        return
    order = {n: i for i, n in enumerate(robot.model.joint_names)}
    names = [p.joint_names[c] for c in cols]
    vmax = robot.model.velocity_limit[[order[n] for n in names]]
    amax = np.array([robot.files.acceleration_limit(n) for n in names])
    rel = 1.0 + s.limit_tolerance_rel
    Q, dt = p.Q[:, cols], p.dt
    v = np.diff(Q, axis=0) / dt  # row i: from point i to i + 1
    a = np.empty_like(Q)  # at each point, with the rest state repeated before and after (a moving column: n >= 2)
    a[1:-1] = np.diff(v, axis=0) / dt
    a[0] = v[0] / dt
    a[-1] = -v[-1] / dt
    vr, ar = np.abs(v).max(axis=0) / vmax, np.abs(a).max(axis=0) / amax
    ctx.note("joint_velocity", max_ratio=float(vr.max()), joint=names[int(np.argmax(vr))])
    ctx.note("joint_acceleration", max_ratio=float(ar.max()), joint=names[int(np.argmax(ar))])
    if np.any(vr > rel):  # column peaks first: the row search only on a violation
        over = np.abs(v) > vmax * rel
        row = _first(over.any(axis=1))
        col = int(np.flatnonzero(over[row])[0])
        raise Veto("joint_velocity", f"joint {names[col]} moves at {abs(v[row, col]):.4f}, limit {vmax[col]:.4f} "
                   f"between points {row} and {row + 1}", row * ctx.S)
    ctx.passed("joint_velocity")
    if np.any(ar > rel):
        over = np.abs(a) > amax * rel
        row = _first(over.any(axis=1))
        col = int(np.flatnonzero(over[row])[0])
        raise Veto("joint_acceleration", f"joint {names[col]} accelerates at {abs(a[row, col]):.4f}, limit "
                   f"{amax[col]:.4f} at point {row}" + (" (the plan does not start/end at rest)" if row in (0, p.n - 1) else ""),
                   row * ctx.S)
    ctx.passed("joint_acceleration")


@dataclass(frozen=True)
class _Grid:
    """The gate's samples: ``S`` per plan interval (controller periods x oversample), then the last point."""

    n: int
    columns: list[np.ndarray]  # per joint (plan order): its n values, or its one value when it holds still
    obj_p: np.ndarray  # (n, 3) object position
    obj_q: np.ndarray  # (n, 4) object quaternion, unit
    point: np.ndarray  # (n,) the plan point whose interval a sample lies in


def _interpolate(p: _Parsed, S: int) -> _Grid:
    """Linear interpolation onto the gate's grid, as the controller plays it.

    A joint that holds one value at every point keeps it in between, so only the moving
    columns are interpolated (plans move a few joints at a time), and the kinematics
    treat the others as constants.
    """
    n, nq = p.n, p.Q.shape[1]
    quat = p.object_pose[:, 3:] / np.linalg.norm(p.object_pose[:, 3:], axis=1, keepdims=True)
    m = (n - 1) * S + 1  # one point: a grid of one sample, that point
    f = np.arange(S) / S

    def lerp(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Rows of a (n, k) and b (n - 1, k) deltas onto the grid: (m, k), written in place."""
        out = np.empty((m, a.shape[1]))
        body = out[:-1].reshape(n - 1, S, a.shape[1])
        np.multiply(f[None, :, None], b[:, None, :], out=body)
        body += a[:-1, None, :]
        out[-1] = a[-1]
        return out

    moving = p.moving
    Qm = p.Q[:, moving]
    rows = lerp(Qm, np.diff(Qm, axis=0)).T.copy()  # (moving joints, m): contiguous per joint
    columns = [p.Q[:1, k] for k in range(nq)]
    for r, k in enumerate(moving):
        columns[k] = rows[r]
    pos = p.object_pose[:, :3]
    P = lerp(pos, np.diff(pos, axis=0))
    q1 = quat[1:] * np.where(np.sum(quat[:-1] * quat[1:], axis=1, keepdims=True) < 0, -1.0, 1.0)  # shortest way
    Qt = lerp(quat, q1 - quat[:-1])
    Qt /= np.linalg.norm(Qt, axis=1, keepdims=True)
    point = np.minimum(np.arange(m) // S, n - 1)
    return _Grid(m, columns, P, Qt, point)


def _rotate(quat: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) ``[x, y, z, w]`` applied to one vector v (3,): (n, 3), without matrices."""
    u, w = quat[:, :3], quat[:, 3:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _check_stability(ctx: _Context, p: _Parsed, fk: BatchFK, polygon: Polygon, s: GateSettings) -> None:
    S = ctx.S
    grid = _interpolate(p, S)
    frames = [f["frame"] for f in p.feet]
    # Exact kinematics at every sample of the grid (controller samples and midpoints).
    robot_com, feet = fk.com_and_points(p.base_pose, grid.columns, grid.n, frames)
    obj_com = grid.obj_p + _rotate(grid.obj_q, p.com_local)
    held = p.holding[grid.point] != 0
    need = ctx.threshold - s.margin_tolerance_m

    # Feet stay where the stance puts them (the polygon below assumes it).
    worst = 0.0
    for foot in p.feet:
        dev = np.linalg.norm(feet[foot["frame"]] - foot["pose"][:3], axis=1)
        k = int(np.argmax(dev))
        worst = max(worst, float(dev[k]))
        if dev[k] > s.feet_tolerance_m:
            first = _first(dev > s.feet_tolerance_m)
            raise Veto("feet", f"sole {foot['frame']} is {dev[first] * 1000:.2f} mm from its stance placement "
                       f"(tolerance {s.feet_tolerance_m * 1000:.1f} mm)", first)
    ctx.passed("feet", max_deviation_m=worst)

    # System CoM (paper eq. 1): robot plus the object while it is held.
    M, m = fk.total_mass, p.mass

    def system(mask: np.ndarray, r: np.ndarray, o: np.ndarray) -> np.ndarray:
        w = m * mask[:, None]
        return (M * r + w * o) / (M + w)

    com = system(held, robot_com, obj_com)
    margin = polygon.margin(com[:, :2])
    k = int(np.argmin(margin))
    ctx.note("com_margin", min_margin_m=float(margin[k]), at_sample=k, threshold_m=ctx.threshold,
             polygon=polygon.vertices.tolist())
    first = _first(margin < need)
    value = float(margin[first]) if first is not None else None
    # Where holding changes at a point, the state there is checked with both values.
    change = np.flatnonzero(p.holding[1:] != p.holding[:-1]) + 1
    if change.size:
        ks = change * S
        before = p.holding[change - 1] != 0
        m2 = polygon.margin(system(before, robot_com[ks], obj_com[ks])[:, :2])
        ctx.note("com_margin", min_margin_at_holding_changes_m=float(m2.min()))
        bad2 = np.flatnonzero(m2 < need)
        if bad2.size and (first is None or ks[bad2[0]] < first):
            first, value = int(ks[bad2[0]]), float(m2[bad2[0]])  # the mass set before the change fails first
    if first is not None:
        raise Veto("com_margin", f"the CoM margin falls to {value * 1000:.2f} mm, below the threshold "
                   f"{ctx.threshold * 1000:.2f} mm (tolerance {s.margin_tolerance_m * 1000:.2f} mm)", first)
    ctx.passed("com_margin")

    # ZMP (cart-table) at every controller sample (5 ms; the plan's points among them),
    # c'' by central differences at dt_s (the contract's step, S gate samples) along the
    # interpolated path. The three states of a stencil use the sample's mass set, so
    # grasping an object is not mistaken for an acceleration; the plan is at rest before
    # and after. With dt_s = 5 ms the controller samples are the plan's points.
    ctrl = np.arange(0, grid.n, s.oversample)
    hk = held[ctrl]
    prev, nxt = np.maximum(ctrl - S, 0), np.minimum(ctrl + S, grid.n - 1)
    c = com[ctrl]
    c_prev = system(hk, robot_com[prev], obj_com[prev])
    c_next = system(hk, robot_com[nxt], obj_com[nxt])
    acc = (c_next[:, :2] - 2.0 * c[:, :2] + c_prev[:, :2]) / (p.dt * p.dt)
    zmp = c[:, :2] - (c[:, 2:3] / s.gravity) * acc
    zm = polygon.margin(zmp)
    k = int(np.argmin(zm))
    ctx.note("zmp", min_margin_m=float(zm[k]), at_sample=int(ctrl[k]), controller_samples=int(ctrl.size))
    row = _first(zm < -s.zmp_tolerance_m)
    if row is not None:
        g = int(ctrl[row])
        where = f"point {g // S}" if g % S == 0 else f"t = {g * p.dt / S:.4f} s, between points {g // S} and {g // S + 1}"
        raise Veto("zmp", f"the ZMP leaves the support polygon by {-zm[row] * 1000:.2f} mm at {where}", g)
    ctx.passed("zmp")
