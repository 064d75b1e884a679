"""The job a controller plays: its buffered segments, the controller's own checks on each, and the playback.

Part of the protocol-and-safety layer of the simulated controller (``controller_sim``): what is buffered and
which commanded posture each instant of plan time gives. What the robot then does with that command is the
plant's business (``plant``).
"""

from __future__ import annotations

import math
import time

import numpy as np

from schemas.bridge import TrajectorySegment

from .controller_settings import ControllerSimSettings, JointLimits


def segment_columns(seg: TrajectorySegment, own: dict[str, int], names: list[str]) -> tuple[np.ndarray, str]:
    """The segment's joint order mapped onto the controller's own, or a problem naming the difference."""
    unknown = [n for n in seg.joint_names if n not in own]
    missing = [n for n in names if n not in seg.joint_names]
    if unknown or missing:
        return np.empty(0, int), f"joint names differ from the controller's: unknown {unknown}, missing {missing}"
    return np.array([own[n] for n in seg.joint_names]), ""


class Job:
    """What the controller knows about the job it plays (or last played)."""

    def __init__(self, seg: TrajectorySegment, columns: np.ndarray):
        self.created = time.monotonic()
        self.playing = False  # the start buffer is full (or waited long enough): playback runs
        self.job_id = seg.job_id
        self.plan_sha256 = seg.plan_sha256
        self.dt = seg.dt_s
        self.segment_count = seg.segment_count
        self.object_mass_kg = seg.object_mass_kg  # the planned payload (the plant's payload check), None: not told
        self.columns = columns  # segment joint order -> own order
        self.last_seq = -1
        self.last_index = -1
        self.points: list[np.ndarray] = []  # one (k, n) block per segment, own order
        self.holding: list[list[str]] = []  # the holding of each point, per block
        self.count = 0
        self.last_heartbeat: float | None = None  # receipt (monotonic) of the last dispatcher heartbeat; armed when set
        self.heartbeat_seq = -1
        self.state = "executing"  # executing | succeeded | stopped | starved | fault | rejected
        self.tau = 0.0  # plan time played so far (s)
        self.index = 0

    def point(self, i: int) -> np.ndarray:
        for block in self.points:
            if i < len(block):
                return block[i]
            i -= len(block)
        raise IndexError(i)

    def holding_at(self, i: int) -> str | None:
        for block in self.holding:
            if i < len(block):
                return block[i]
            i -= len(block)
        return None

    @property
    def complete(self) -> bool:
        return self.last_index == self.segment_count - 1

    def drop(self) -> int:
        """Drop every buffered point (the job ended); returns how many were not played."""
        dropped = max(0, self.count - self.index - 1)
        self.points, self.holding = [], []
        return dropped

    def accept(self, seg: TrajectorySegment, q_now: np.ndarray, limits: JointLimits, names: list[str],
               sim: ControllerSimSettings) -> tuple[str, str]:
        """The controller's own checks on a segment; buffers it when they pass (called with the lock held)."""
        if (seg.plan_sha256 != self.plan_sha256 or abs(seg.dt_s - self.dt) > 1e-12 or seg.segment_count != self.segment_count
                or seg.object_mass_kg != self.object_mass_kg):
            return "rejected", "plan_sha256, dt_s, segment_count or object_mass_kg changed within a job"
        first = int(round(seg.t_from_start / seg.dt_s))
        if first != self.count:
            return "rejected", f"t_from_start {seg.t_from_start} does not continue the buffered {self.count} points"
        pts = np.empty((len(seg.points), len(names)))
        pts[:, self.columns] = np.array(seg.points, dtype=float)
        tol = sim.position_tolerance
        bad = np.argwhere((pts < limits.lower - tol) | (pts > limits.upper + tol))
        if bad.size:
            i, j = bad[0]
            return "rejected", (f"joint limit: {names[j]} = {pts[i, j]:.4f} outside "
                                f"[{limits.lower[j]:.4f}, {limits.upper[j]:.4f}]")
        prev = q_now if self.count == 0 else self.point(self.count - 1)
        if self.count == 0:
            dev = np.abs(pts[0] - prev)
            j = int(np.argmax(dev))
            if dev[j] > sim.start_tolerance_rad:
                return "rejected", f"start mismatch: {names[j]} is {dev[j]:.4f} from the current posture"
        steps = np.abs(np.diff(np.vstack([prev[None], pts]), axis=0)) / seg.dt_s
        if self.count == 0:
            steps = steps[1:]
        over = np.argwhere(steps > limits.velocity * (1.0 + sim.limit_tolerance_rel) + 1e-12)
        if over.size:
            i, j = over[0]
            return "rejected", f"velocity limit: {names[j]} at {steps[i, j]:.3f}, limit {limits.velocity[j]:.3f}"
        self.points.append(pts)
        self.holding.append(list(seg.holding))
        self.count += len(pts)
        self.last_seq, self.last_index = seg.seq, seg.segment_index
        return "accepted", f"{len(pts)} points buffered ({self.count} in all)"

    def ready(self, now: float, sim: ControllerSimSettings) -> bool:
        """Whether playback runs: the start buffer is full, the whole job is held, or the buffer waited its length."""
        if not self.playing:
            held_s = (self.count - 1) * self.dt / sim.speed
            self.playing = self.complete or held_s >= sim.start_buffer_s or now - self.created >= sim.start_buffer_s
        return self.playing

    def advance(self, step: float, limits: JointLimits, tol: float) -> tuple[np.ndarray | None, str | None, tuple[str, str] | None]:
        """Move the playback by ``step`` plan seconds: (commanded posture, its holding, the event that ended the
        job or None). At the end of the job the last point is commanded and the job ``succeeded``; when the next
        point is missing the job ``starved`` (hold the last command); a posture past a limit is a ``fault``."""
        tau = self.tau + step
        f = tau / self.dt
        i = int(math.floor(f))
        total = self.count
        if self.complete and i >= total - 1:
            q, holding = self.point(total - 1).copy(), self.holding_at(total - 1)
            self.tau, self.index = (total - 1) * self.dt, total - 1
            return q, holding, ("succeeded", f"{total} points played")
        if i + 1 >= total:
            return None, None, ("starved", f"point {i + 1} missing (segment {self.last_index + 1} not received); "
                                           "holding posture")
        a, b = self.point(i), self.point(i + 1)
        q = a + (f - i) * (b - a)
        if np.any(q < limits.lower - tol) or np.any(q > limits.upper + tol):
            return None, None, ("fault", "joint limit reached during playback; holding posture")
        self.tau, self.index = tau, i
        return q, self.holding_at(i), None
