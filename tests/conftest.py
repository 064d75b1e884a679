"""Shared fixtures: the robot models are loaded once per test session."""

from __future__ import annotations

import os
import time

import pytest

# Keep caches (grasps, etc.) inside the test run, never in the user's home.
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def hrp5p():
    from planner.robot.model import load_robot

    return load_robot("hrp5p")


@pytest.fixture(scope="session")
def stances(hrp5p):
    from planner.stability.stances import BUILTIN_STANCES, solve_stance

    return {name: solve_stance(hrp5p, name) for name in BUILTIN_STANCES}


@pytest.fixture(scope="session")
def host_stalls():
    """The host-stall probe (``tests/host_stalls.py``): timing tests allow the time the host stole."""
    return host_stall_probe()


def pytest_sessionstart(session):
    """The planner's compiled kernels ready before any test starts a timed job or a subprocess: a fresh
    checkout compiles them once here (~10 s on two cores), and every process after loads them from
    numba's cache (planner/warmup.py).

    The session's surveys are cached in a folder of the run's own (subprocesses inherit it), never in the
    user's ``~/.cache``: a test sees what it computes in this run, as on a clean CI machine."""
    import tempfile

    from planner.warmup import warm_up

    os.environ["REGRASP_SURVEY_CACHE_DIR"] = tempfile.mkdtemp(prefix="regrasp-test-surveys-")
    warm_up()


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        "host_pauses(limit_s, attempts=3): a test whose outcome depends on wall-clock time; when it fails while the "
        "VM's host paused every process of the guest for limit_s or more, the failure measured the host and the test "
        "runs again (at most attempts in all; the last one counts)",
    )


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_protocol(item, nextitem):
    """Runs ``host_pauses`` tests again after a failure during a host pause (see the marker); every other test as
    pytest does. A failure with no such pause fails at once, and each pause that caused a re-run is printed."""
    marker = item.get_closest_marker("host_pauses")
    if marker is None:
        return None
    from _pytest.runner import runtestprotocol

    limit_s = marker.kwargs.get("limit_s", marker.args[0] if marker.args else 0.2)
    attempts = marker.kwargs.get("attempts", 3)
    probe = host_stall_probe()
    item.ihook.pytest_runtest_logstart(nodeid=item.nodeid, location=item.location)
    for attempt in range(1, attempts + 1):
        started = time.monotonic()
        reports = runtestprotocol(item, nextitem=nextitem, log=False)
        if not any(r.failed for r in reports) or attempt == attempts:
            break
        longest = max(probe.stalls_between(started, time.monotonic()), default=0.0)  # after a failure only
        if longest < limit_s:
            break
        reporter = item.config.pluginmanager.get_plugin("terminalreporter")
        if reporter is not None:
            reporter.write_line(f"\n{item.nodeid}: failed while the host paused the guest for {longest * 1000:.0f} ms "
                                f"(attempt {attempt} of {attempts}); running it again")
    for report in reports:
        item.ihook.pytest_runtest_logreport(report=report)
    item.ihook.pytest_runtest_logfinish(nodeid=item.nodeid, location=item.location)
    return True


_PROBE = None


def host_stall_probe():
    """The session's one host-stall probe, started on first use (its subprocess ends with the session)."""
    global _PROBE
    if _PROBE is None:
        from host_stalls import HostStallProbe

        _PROBE = HostStallProbe()
    return _PROBE


def pytest_unconfigure(config):
    if _PROBE is not None:
        _PROBE.close()


def pytest_sessionfinish(session, exitstatus):
    """The run's survey cache goes with the run."""
    import shutil
    import tempfile

    folder = os.environ.get("REGRASP_SURVEY_CACHE_DIR", "")
    if os.path.basename(folder).startswith("regrasp-test-surveys-") and folder.startswith(tempfile.gettempdir()):
        shutil.rmtree(folder, ignore_errors=True)


#: Test files that start a local Ray instance or cluster: under pytest-xdist they run one after another.
RAY_FILES = ("tests/service/test_service_ray.py", "tests/service/test_service_ray_cluster.py",
             "tests/service/test_service_shutdown.py")


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """With ``--dist loadgroup`` (scripts/test.sh), every file is one group, so a file's module fixtures are set up
    once, and the files that start Ray share one group. The groups are read where the tests are collected, on the
    workers, which pytest-xdist runs with ``dist`` "no" and its own ``loadgroup`` flag set."""
    if config.getoption("dist", default="no") != "loadgroup" and not getattr(config.option, "loadgroup", False):
        return
    for item in items:
        path = item.nodeid.split("::", 1)[0]
        item.add_marker(pytest.mark.xdist_group("ray" if path in RAY_FILES else path))
