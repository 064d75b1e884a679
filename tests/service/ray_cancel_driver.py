"""A driver on a Ray cluster (a test helper): seeds stuck in a long C call, then their session closed as cancelled.

``python tests/service/ray_cancel_driver.py ADDRESS`` connects to the cluster, opens a
:class:`service.executors.ray_seeds.RaySeeds` session whose seeds sleep 20 s inside libc (no Python
bytecode runs, so a soft cancel cannot reach them), waits until two of them hold CPUs, closes the session
as a cancelled job does, and prints one JSON line: how long the cluster took to have its CPUs free again.
"""

from __future__ import annotations

import ctypes
import json
import sys
import time


def stuck_seed(hands: str, seed: int, keep: bool) -> int:
    ctypes.CDLL(None).sleep(20)  # one long C call: the interpreter never gets to raise an interrupt
    return seed


def main() -> None:
    import ray

    from service.executors.ray_seeds import RaySeeds, connect

    connect(sys.argv[1])
    free = lambda: ray.available_resources().get("CPU", 0.0)  # noqa: E731
    before = free()
    session = RaySeeds().open(stuck_seed)
    for k in range(2):
        session.submit("left-left", k, False)
    deadline = time.monotonic() + 120
    while free() > before - 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    busy = free()
    t0 = time.monotonic()
    session.close(cancel=True)
    while free() < before and time.monotonic() - t0 < 15:
        time.sleep(0.2)
    print(json.dumps({"before": before, "busy": busy, "after": free(), "freed_s": time.monotonic() - t0}), flush=True)
    ray.shutdown()


if __name__ == "__main__":
    main()
