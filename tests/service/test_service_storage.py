"""A sick service says so: a real server on a small tmpfs that fills up, then turns read-only.

/healthz answers 503 with the reason, a submission is refused with 503 and the reason, the running
job fails with a reason naming the disk, nothing is left in ``planning``, the log holds no traceback;
and the service is healthy again once there is room. Needs root (``mount -t tmpfs``); the tmpfs is
unmounted afterwards.
"""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path
from typing import Iterator

import pytest
from conftest import Server, wait_state

#: Size of the test's disk, and the free space below which the service is sick.
DISK = "24m"
MIN_FREE = 4_000_000
#: How soon the service must notice (its check runs every second; a loaded machine is slower).
NOTICE_S = 10.0


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK},mode=0700", "tmpfs", str(mnt)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def _fill(path: Path) -> None:
    """Write until the disk is full."""
    chunk = b"\0" * (256 * 1024)
    with open(path, "wb", buffering=0) as fh:
        try:
            while True:
                fh.write(chunk)
        except OSError:
            pass


def _until(predicate, timeout: float = NOTICE_S):  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value or time.monotonic() > deadline:
            return value
        time.sleep(0.2)


def test_full_then_read_only_disk_makes_the_service_say_it_is_sick(small_disk: Path, tmp_path: Path) -> None:
    data = small_disk / "var"
    srv = Server(data, workers=1, disk_min_free_bytes=str(MIN_FREE), disk_reserve_bytes=str(1_000_000))
    srv.log_path = tmp_path / "server.log"  # the log stays writable whatever happens to the disk
    try:
        srv.start()
        with srv.client("alice") as c:
            assert c.get("/healthz").status_code == 200
            running = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "busy-30"}}).json()["id"]
            wait_state(c, running, {"planning"}, 30)

            _fill(small_disk / "ballast")
            sick = _until(lambda: (r := c.get("/healthz")).status_code == 503 and r)
            assert sick, "healthz never said the disk is full"
            assert "full" in sick.json()["detail"] and str(data) in sick.json()["detail"], sick.json()
            refused = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "quick"}})
            assert refused.status_code == 503 and "disk" in refused.json()["detail"], refused.text
            assert refused.headers["content-type"].startswith("application/problem+json")
            job = wait_state(c, running, {"failed", "succeeded", "planned", "canceled"}, NOTICE_S)
            assert job["state"] == "failed" and job["error"]["code"] == "STORAGE_UNAVAILABLE", job
            assert "disk" in job["error"]["message"] and "full" in job["error"]["message"]
            assert not [j for j in c.get("/v1/jobs").json()["jobs"] if j["state"] == "planning"]

            (small_disk / "ballast").unlink()  # room again: healthy, and jobs are taken
            assert _until(lambda: c.get("/healthz").status_code == 200)
            again = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "quick"}})
            assert again.status_code == 202
            assert wait_state(c, again.json()["id"], {"planned", "failed"}, 30)["state"] == "planned"

            # Read-only: the data directory mounted again over itself, read-only (the store's open files keep
            # their old mount; every new file, such as the service's probe, gets EROFS).
            subprocess.run(["mount", "--bind", str(data), str(data)], check=True)
            subprocess.run(["mount", "-o", "remount,bind,ro", str(data)], check=True)
            try:
                ro = _until(lambda: (r := c.get("/healthz")).status_code == 503 and r)
                assert ro and "read-only" in ro.json()["detail"], ro and ro.json()
                refused = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "quick"}})
                assert refused.status_code == 503 and "read-only" in refused.json()["detail"]
            finally:
                subprocess.run(["umount", "-l", str(data)], check=True)
            assert _until(lambda: c.get("/healthz").status_code == 200)
    finally:
        srv.stop()
    log = srv.log_path.read_text()
    assert "Traceback" not in log, log[-4000:]
