"""What the gate's checks found so far, and how it becomes the verdict (:class:`schemas.bridge.GateVerdict`)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.bridge import GateVerdict

from .gate_types import GateSettings


@dataclass
class _Context:
    """What the checks found so far; becomes the verdict."""

    settings: GateSettings
    S: int = 1
    n_points: int = 0
    dt: float = 0.0
    samples: int = 0
    threshold: float | None = None
    #: A recover job's plan (from a measured state back to the stance): the margin floor is the threshold or,
    #: where the start is below it, the start's own margin (never lowered).
    recovery: bool = False
    plan_sha256: str | None = None
    digest: tuple[str, float] | None = None  # (sha256 of the given bytes, seconds it took)
    policy_sha256: str | None = None  # the safety policy that judges the plan

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
            plan_sha256=self.plan_sha256, threshold_m=self.threshold, policy_sha256=self.policy_sha256, samples=self.samples,
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


def _timed(ctx: "_Context", what: str, fn: Any, *args: Any) -> Any:
    """Run ``fn`` and record its wall time under ``stats['timing'][what]``."""
    t0 = time.perf_counter()
    try:
        return fn(*args)
    finally:
        ctx.note("timing", **{what: time.perf_counter() - t0})
