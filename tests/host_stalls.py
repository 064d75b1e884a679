"""How long the host kept every process of the test run from running, measured by a process of its own.

The CI machine is a VM whose host takes the CPU in bursts: every process of the guest stops at
once, for tens of milliseconds and at times over a second, while the clocks run on. A deadline
test (abort within 300 ms of losing the controller, 200 Hz joint states) measured across such a
pause measures the host, not the bridge. This probe is a separate process that wakes every
``period_s`` and reports each wake-up that came late; a stall that hit it hit the whole guest.
Being outside the test's process, it does not see the test's own interpreter (a thread holding
the GIL, a collection), so a slow bridge is never excused by it.

``stolen_between(t0, t1)`` is the time within [t0, t1] during which the probe could not run;
timing tests allow that much on top of their deadline and print it.
"""

from __future__ import annotations

import bisect
import subprocess
import sys
import threading
import time

from planner.forking import declare_fork_benign

#: A wake-up this much later than asked counts as a stall (the probe runs at real-time priority
#: where it may, so the guest's own busy processes do not delay it; where it may not, a 2-core
#: guest running three busy processes delays a wake-up by a few ms without any stall of the host).
LATE_S = 0.015

_SAMPLER = """
import os, sys, time
period, late = float(sys.argv[2]), float(sys.argv[1])
try:  # SCHED_FIFO: only the host (or the kernel's interrupts) can hold a real-time sleeper back
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    mode = "realtime"
except (OSError, AttributeError):
    mode = "normal"
last = time.monotonic()
print("ready", mode, flush=True)
while True:
    time.sleep(period)
    now = time.monotonic()
    if now - last > period + late:
        sys.stdout.write(f"{last!r} {now!r}\\n")
        sys.stdout.flush()
    last = now
"""


class HostStallProbe:
    """A sampler subprocess and the stalls it reported, as (start, end) monotonic times (the clock is system-wide)."""

    def __init__(self, late_s: float = LATE_S, period_s: float = 0.005) -> None:
        self.late_s = late_s
        self.mode = "starting"  # "realtime" or "normal" once the sampler runs
        self._proc = subprocess.Popen([sys.executable, "-c", _SAMPLER, repr(late_s), repr(period_s)],
                                      stdout=subprocess.PIPE, text=True, bufsize=1)
        self._lock = threading.Lock()
        self._starts: list[float] = []
        self._ends: list[float] = []
        self._ready = threading.Event()
        self._reader = threading.Thread(target=self._read, name="host-stall-probe", daemon=True)
        # it only reads the sampler's pipe into its own lists: a forked planner helper never touches either
        declare_fork_benign(self._reader)
        self._reader.start()
        if not self._ready.wait(30.0):
            self.close()
            raise RuntimeError("the host-stall probe did not start")

    def _read(self) -> None:
        assert self._proc.stdout is not None
        for line in self._proc.stdout:
            if line.startswith("ready"):
                self.mode = line.split()[1]
                self._ready.set()
                continue
            start, end = (float(x) for x in line.split())
            with self._lock:
                self._starts.append(start)
                self._ends.append(end)

    def stalls_between(self, t0: float, t1: float, settle_s: float = 0.05) -> list[float]:
        """The part of each reported stall that lies in [t0, t1] (seconds). Waits ``settle_s`` first: a
        stall that ends just before t1 is reported a moment later."""
        time.sleep(settle_s)
        with self._lock:
            first = bisect.bisect_left(self._ends, t0)
            spans = list(zip(self._starts[first:], self._ends[first:]))
        return [min(end, t1) - max(start, t0) for start, end in spans if start < t1]

    def stolen_between(self, t0: float, t1: float) -> float:
        """Seconds of [t0, t1] during which the host let no process of the guest run."""
        return sum(self.stalls_between(t0, t1))

    def close(self) -> None:
        self._proc.kill()
        self._proc.wait(timeout=5)
