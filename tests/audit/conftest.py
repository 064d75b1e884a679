"""Fixtures for the audit tests: a small, realistic audit file."""

from __future__ import annotations

from pathlib import Path

import pytest

from planner.robot.registry import urdf_path


@pytest.fixture(scope="session")
def hrp5p_urdf() -> str:
    return urdf_path("hrp5p").read_text()


def tiny_plan(n: int = 12) -> dict:
    """A plan-shaped dict (docs/contract.md section 3 fields the writer reads)."""
    names = ["LCY", "LCR", "RCY"]
    return {
        "robot": {"name": "hrp5p", "joint_names": names},
        "stance": {"base_pose": [0.0, 0.0, 0.9, 0.0, 0.0, 0.0, 1.0]},
        "support_polygon": [[0.12, 0.17], [-0.12, 0.17], [-0.12, -0.17], [0.12, -0.17]],
        "threshold_m": 0.06,
        "dt_s": 0.005,
        "trajectory": [
            {"t": i * 0.005, "q": [0.01 * i, 0.0, -0.01 * i], "com": [0.001 * i, 0.0, 0.85], "margin_m": 0.1 - 0.001 * i}
            for i in range(n)
        ],
    }


def write_sample(path: Path, urdf: str | None, *, close: bool = True, compression: str = "none") -> list[str]:
    """Write a job's audit file; returns the head after every call.

    Uncompressed by default, so that tests can find and edit a record's bytes in the file.
    """
    from service.audit import AuditSettings, AuditWriter

    heads = []
    w = AuditWriter(path, "job-42", robot_name="hrp5p", urdf_text=urdf, clock_ns=_Clock(),
                    settings=AuditSettings(compression=compression))
    heads.append(w.head)
    heads.append(w.state_change(None, "queued", actor="alice"))
    heads.append(w.record("request", {"scenario": "upright", "threshold_m": 0.06}))
    heads.append(w.state_change("queued", "planning"))
    heads.append(w.support_markers(tiny_plan()["support_polygon"], threshold_m=0.06))
    heads.append(w.plan_playback(tiny_plan()))
    heads.append(w.record("plan", {"status": "solved", "min_margin_m": 0.089}))
    heads.append(w.com_marker([0.0, 0.0, 0.85], margin_m=0.05, threshold_m=0.06))
    heads.append(w.joint_state(["LCY", "LCR", "RCY"], [0.1, 0.2, 0.3], source="executed",
                               base_pose=[0, 0, 0.9, 0, 0, 0, 1]))
    heads.append(w.log("gate passed", level="info"))
    if close:
        heads.append(w.close())
    return heads


class _Clock:
    """Deterministic nanosecond clock: +1 ms per call."""

    def __init__(self, start: int = 1_700_000_000_000_000_000) -> None:
        self.now = start

    def __call__(self) -> int:
        self.now += 1_000_000
        return self.now
