"""The ``host_pauses`` marker (tests/conftest.py): a timing test that failed while the VM's host paused the guest
runs again; one that failed with no pause fails at once. A pause is simulated by stopping the probe's process."""

from __future__ import annotations

from pathlib import Path

pytest_plugins = ["pytester"]

TESTS = Path(__file__).resolve().parent

BODY = """
import os, signal, time
import pytest
from conftest import host_stall_probe

RUNS = []

def pause_the_probe(seconds):
    pid = host_stall_probe()._proc.pid
    time.sleep(0.05)
    os.kill(pid, signal.SIGSTOP)
    time.sleep(seconds)
    os.kill(pid, signal.SIGCONT)

@pytest.mark.host_pauses(limit_s=0.2)
def test_fails_during_a_pause_then_passes():
    RUNS.append(1)
    if len(RUNS) == 1:
        pause_the_probe(0.4)
        assert False, "late"

@pytest.mark.host_pauses(limit_s=0.2)
def test_fails_without_a_pause():
    RUNS.append(2)
    assert False, "a real failure"

@pytest.mark.host_pauses(limit_s=0.2, attempts=2)
def test_fails_in_every_attempt():
    RUNS.append(3)
    pause_the_probe(0.3)
    assert False, "still late"

def test_zz_counts():
    assert RUNS.count(1) == 2 and RUNS.count(2) == 1 and RUNS.count(3) == 2, RUNS
"""


def test_failures_during_host_pauses_run_again(pytester):
    pytester.makeconftest((TESTS / "conftest.py").read_text())
    pytester.makepyfile(host_stalls=(TESTS / "host_stalls.py").read_text(), test_timing=BODY)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-q", timeout=120)
    result.assert_outcomes(passed=2, failed=2)
    result.stdout.fnmatch_lines(["*test_fails_during_a_pause_then_passes: failed while the host paused the guest for *"
                                 " ms (attempt 1 of 3); running it again*"])
    assert "test_fails_without_a_pause: failed while" not in result.stdout.str()
