"""Child process for the crash test: writes a job's audit file until killed.

Prints the chain head after every call (one per line, flushed) so the parent
knows what reached the file before it sends SIGKILL.
"""

from __future__ import annotations

import sys

from planner.robot.registry import urdf_path
from service.audit import AuditWriter
from tests.audit.conftest import tiny_plan


def main(path: str) -> None:
    w = AuditWriter(path, "job-crash", robot_name="hrp5p", urdf_text=urdf_path("hrp5p").read_text())
    print(w.head, flush=True)
    plan = tiny_plan(400)
    i = 0
    while True:  # runs until the parent kills it (the parent's timeout bounds the test)
        i += 1
        print(w.state_change("executing", "executing", reason=f"tick {i}"), flush=True)
        print(w.joint_state(["LCY", "LCR", "RCY"], [0.001 * i, 0.0, 0.0], base_pose=[0, 0, 0.9, 0, 0, 0, 1]), flush=True)
        if i % 5 == 0:
            print(w.plan_playback(plan), flush=True)


if __name__ == "__main__":
    main(sys.argv[1])
