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
import math
import threading
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

import numpy as np

from schemas.bridge import GateVerdict
from schemas.plan import plan_sha256
from schemas.policy import SafetyPolicy, default_policy

from .gate_checks import (
    _check_finite,
    _check_position,
    _check_rates,
    _check_start,
    _check_time,
    _limits,
)
from .gate_effort import EffortVeto, check_effort_and_grip
from .gate_context import _Context, _first, _jsonable, _timed
from .gate_policy import check_policy_limits, check_policy_threshold
from .gate_parse import (
    ExecutablePlan,
    _parse_executable,
    decode_executable,
    _find_bad_point,
    _floats,
    _get,
    _parse,
    _Parsed,
    _reject_constant,
    loads_plan,
)
from .gate_stability import _check_stability, _Grid, _interpolate, _rotate
from .gate_types import _HOLDING, Approval, GateSettings, MeasuredState, Veto, _Robot
from .robot_files import robot_files
from .support import support_polygon
from .urdf_kinematics import BatchFK, load_urdf

#: The gate's parts live in robot_bridge.gate_* modules; these names stay importable from here.
__all__ = ["Approval", "ExecutablePlan", "GateSettings", "MeasuredState", "SafetyGate", "Veto", "loads_plan", "_HOLDING", "_Context",
           "_Grid", "_Parsed", "_Robot", "_check_finite", "_check_position", "_check_rates", "_check_stability",
           "_check_start", "_check_time", "_find_bad_point", "_first", "_floats", "_get", "_interpolate", "_jsonable",
           "_limits", "_parse", "_reject_constant", "_rotate", "_timed"]


class SafetyGate:
    """Checks plans for one process against one site's safety policy; robot models are parsed once and cached.

    The policy (:mod:`schemas.policy`, the built-in one by default: a 30 mm floor) is the gate's own: no
    argument of a check can lower its floor, and every verdict carries its SHA-256."""

    def __init__(self, settings: GateSettings | None = None, policy: SafetyPolicy | None = None):
        self.settings = settings or GateSettings()
        self.policy = policy or default_policy()
        self._policy_sha256 = self.policy.sha256()
        self._robots: dict[tuple[str, str], _Robot] = {}
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
        recovery: bool = False,
        physics: dict[str, Any] | None = None,
    ) -> GateVerdict:
        """The verdict on ``plan``. Online (the default) an approval and a measured state are required.

        ``offline`` skips the approval, hash and start-state checks when they are not
        given (``regrasp gate check``); every other check runs the same way. ``threshold_m`` replaces
        the plan's threshold for the samples, never below the policy's floor. ``physics``: the plan's
        physics dry run (``regrasp.simreport/1``), needed when the policy requires one.
        """
        return self._check(plan, None, approval, measured, threshold_m, now, offline, recovery=recovery,
                           physics=physics)

    def check_json(self, plan_json: bytes | str,
                   **kwargs: Any) -> tuple[GateVerdict, ExecutablePlan | dict[str, Any] | None]:
        """Check a plan given as its canonical JSON bytes; returns the verdict and the plan as the gate read it.

        The fast path for large plans: the SHA-256 is taken over the bytes as they are
        (milliseconds) instead of re-serialising the plan (about a second for a 60 s plan), and
        the bytes are decoded straight into the checked fields (:class:`ExecutablePlan`, msgspec),
        which is what the dispatcher then sends. Sound because equal hashes mean equal bytes:
        bytes that are not the approved canonical JSON fail the hash check. A plan the typed
        reading does not take is parsed as a document (orjson) and checked as :meth:`check`
        does, naming what is wrong; the document is then what is returned. Keyword arguments as
        :meth:`check`.
        """
        raw = plan_json.encode() if isinstance(plan_json, str) else bytes(plan_json)
        t0 = time.perf_counter()
        # The bytes are decoded in a thread while this one hashes them: hashlib releases the GIL while it hashes,
        # msgspec holds it while it decodes, so the two overlap.
        decoded: list[ExecutablePlan | None] = []
        decoder = threading.Thread(target=lambda: decoded.append(decode_executable(raw)), name="gate-decode", daemon=True)
        t1 = time.perf_counter()
        decoder.start()
        digest, hash_s = _sha256_timed(raw)
        decoder.join()
        executable = decoded[0] if decoded else None
        plan: Any = _Decoded(executable, raw) if executable is not None else None
        if plan is None:
            try:
                plan = loads_plan(raw)
            except (ValueError, RecursionError) as exc:
                ctx = _Context(settings=self.settings, policy_sha256=self._policy_sha256)
                return ctx.verdict(False, "structure", f"the plan is not valid JSON: {exc}", None,
                                   time.perf_counter() - t0), None
        verdict = self._check(plan, (digest, hash_s), kwargs.pop("approval", None), kwargs.pop("measured", None),
                              kwargs.pop("threshold_m", None), kwargs.pop("now", None), kwargs.pop("offline", False),
                              json_s=time.perf_counter() - t1, recovery=kwargs.pop("recovery", False),
                              physics=kwargs.pop("physics", None), **kwargs)
        return verdict, (executable if executable is not None else plan)

    def _check(self, plan: Any, digest: tuple[str, float] | None, approval: Approval | None, measured: MeasuredState | None,
               threshold_m: float | None, now: datetime | None, offline: bool, json_s: float | None = None,
               recovery: bool = False, physics: dict[str, Any] | None = None) -> GateVerdict:
        started = time.perf_counter()
        ctx = _Context(settings=self.settings, policy_sha256=self._policy_sha256)
        ctx.recovery = recovery
        ctx.digest = digest
        if json_s is not None:  # check_json: reading the bytes into a plan, before the checks (not in elapsed_s)
            ctx.note("timing", json_s=json_s)
        try:
            self._run(ctx, plan, approval, measured, threshold_m, now, offline, physics)
        except Veto as veto:
            return ctx.verdict(False, veto.check, veto.message, veto.sample_index, time.perf_counter() - started)
        except Exception as exc:  # fail closed: the gate's own failure is a veto
            return ctx.verdict(False, "gate_error", f"the gate could not check the plan: {type(exc).__name__}: {exc}", None,
                               time.perf_counter() - started)
        return ctx.verdict(True, None, "every check passed", None, time.perf_counter() - started)

    # ------------------------------------------------------------------ internals
    def _robot(self, name: str, urdf_sha256: str = "") -> _Robot:
        """The robot a plan names, with the URDF of the plan's SHA-256 where the robot's is derived (several
        derived URDFs of one robot can be in the cache)."""
        files = robot_files(name, urdf_sha256)
        key = (name, str(files.urdf))  # by file: a plan's made-up SHA-256 adds nothing here
        if key not in self._robots:
            self._robots[key] = _Robot(files=files, model=load_urdf(str(files.urdf)), urdf_sha256=files.urdf_sha256)
        return self._robots[key]

    def _batch_fk(self, robot: _Robot, joint_names: tuple[str, ...]) -> BatchFK:
        key = (robot.files.name, joint_names)
        if key not in self._fk:
            self._fk[key] = BatchFK(robot.model, joint_names)
        return self._fk[key]

    def _run(self, ctx: "_Context", plan: dict, approval: Approval | None, measured: MeasuredState | None,
             threshold_m: float | None, now: datetime | None, offline: bool,
             physics: dict[str, Any] | None = None) -> None:
        s = self.settings
        p = _timed(ctx, "parse_s", _read, ctx, plan, s)
        robot = self._robot(p.robot_name, p.urdf_sha256)
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

        # The site's policy first: a plan made below its floor is not read on; the samples are checked
        # against the larger of the threshold and the floor.
        ctx.threshold = check_policy_threshold(ctx, p, self.policy, threshold_m)

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
        check_policy_limits(ctx, p, self.policy, physics)

        # The torque and grip checks need only the plan's points: they run in a thread of their own while the
        # checks below do (numpy releases the GIL in its loops); their verdict comes after the stability check's.
        effort = _EffortRun(robot, p, s, ctx.S) if s.check_limits else None
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
        if effort is not None:  # static joint torques and grip (robot_bridge.gate_effort)
            figures = _timed(ctx, "effort_wait_s", effort.result)
            ctx.note("timing", effort_s=effort.elapsed_s)
            ctx.passed("effort", max_ratio=figures["max_effort_ratio"])
            ctx.passed("grip", max_ratio=figures["max_grip_ratio"])


class _EffortRun:
    """:func:`check_effort_and_grip` on a plan's points, in a thread started at construction.

    A plain thread per check (not a pool): a pool's thread would not survive a fork of the process,
    and a forked child's gate would then wait for ever."""

    def __init__(self, robot: _Robot, p: _Parsed, s: GateSettings, samples_per_point: int):
        self._S = samples_per_point
        self._args = (robot.model, robot.files.spec, p.joint_names, p.Q, p.base_pose, p.holding, p.object_pose,
                      p.com_local, p.mass, p.feet, s.gravity)
        self._figures: dict[str, Any] | None = None
        self._error: BaseException | None = None
        self.elapsed_s = 0.0
        self._thread = threading.Thread(target=self._work, name="gate-effort", daemon=True)
        self._thread.start()

    def _work(self) -> None:
        t0 = time.perf_counter()
        try:
            with np.errstate(all="ignore"):  # non-finite torques are vetoed by value, not warned about
                self._figures = check_effort_and_grip(*self._args)
        except BaseException as exc:  # handed to the caller: a veto, or the gate's own failure (fails closed)
            self._error = exc
        self.elapsed_s = time.perf_counter() - t0

    def result(self) -> dict[str, Any]:
        """The figures; raises the effort or grip veto (at its sample), or the check's own error."""
        self._thread.join()
        if isinstance(self._error, EffortVeto):
            raise Veto(self._error.check, self._error.message, self._error.point * self._S) from None
        if self._error is not None:
            raise self._error
        assert self._figures is not None
        return self._figures


def _sha256_timed(raw: bytes) -> tuple[str, float]:
    t0 = time.perf_counter()
    return hashlib.sha256(raw).hexdigest(), time.perf_counter() - t0


@dataclass(frozen=True)
class _Decoded:
    """The typed fields :meth:`SafetyGate.check_json` decoded, with the bytes they came from."""

    plan: ExecutablePlan
    raw: bytes


def _read(ctx: "_Context", plan: Any, s: GateSettings) -> _Parsed:
    """The gate's arrays of a plan document, or of the typed fields :meth:`SafetyGate.check_json` decoded."""
    if isinstance(plan, _Decoded):
        parsed = _parse_executable(plan.plan, s)
        if parsed is not None:
            return parsed
        plan = loads_plan(plan.raw)  # a value out of range: the document's reading names it, as check() does
    return _parse(ctx, plan, s)


def _digest(ctx: "_Context", plan: Any) -> str:
    """The plan's SHA-256: over the bytes given to :meth:`SafetyGate.check_json`, else over its canonical JSON."""
    if ctx.digest is not None:
        ctx.note("timing", hash_s=ctx.digest[1])
        return ctx.digest[0]
    return _timed(ctx, "hash_s", plan_sha256, plan)
