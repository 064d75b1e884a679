"""A writer killed with SIGKILL mid-job leaves a file that reads up to its last record."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from service.audit import ExitCode, verify

ROOT = Path(__file__).resolve().parents[2]
HEADS_BEFORE_KILL = 40
CHILD_TIMEOUT_S = 60.0


@pytest.mark.parametrize("extra_ms", [0, 3])
def test_kill_minus_9_mid_job_leaves_an_unfinished_but_intact_file(tmp_path, extra_ms):
    path = tmp_path / "job.mcap"
    child = subprocess.Popen(
        [sys.executable, "-m", "tests.audit.crash_writer", str(path)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )
    heads: list[str] = []
    deadline = time.monotonic() + CHILD_TIMEOUT_S
    try:
        assert child.stdout is not None
        while len(heads) < HEADS_BEFORE_KILL and time.monotonic() < deadline:
            line = child.stdout.readline()
            if not line:
                break
            heads.append(line.strip())
        time.sleep(extra_ms / 1000.0)  # kill at a different point of the write loop
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=10)
    assert len(heads) == HEADS_BEFORE_KILL, "the writer did not start"

    result = verify(path, keep_records=True)
    assert result.exit_code == ExitCode.UNFINISHED, result.detail
    assert not result.finished
    digests = [entry.digest for entry in result.entries]
    # Everything the writer reported as written is in the file, in chain order.
    positions = [digests.index(h) for h in heads]
    assert positions == sorted(positions)
    # The file reads up to its last complete record, and that record verifies as the head.
    assert result.head == digests[-1]
    assert verify(path, result.head).exit_code == ExitCode.UNFINISHED
    # A head from before the end is not where the chain ends: broken.
    if digests[-1] != heads[0]:
        assert verify(path, heads[0]).exit_code == ExitCode.BROKEN
