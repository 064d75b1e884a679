"""The console draws the robot's centre of pressure live beside the planned ZMP: the real service, a real
``regrasp controller-sim --plant physics`` (the MuJoCo twin's ``state/balance``) and headless Chromium. While the
job executes the page's CoM chart gains CoP points, and they lie where the robot stands: on the planned ZMP of a
plan that stands still."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from typing import Iterator

import pytest
from playwright.sync_api import expect

from tests.service.conftest import TOKEN as SERVICE_TOKENS
from tests.service.conftest import (
    BRIDGE_LEASE_S,
    BRIDGE_ROBOT_ID,
    BRIDGE_WATCHDOG_S,
    ROOT,
    Server,
    bridge_keys,
    free_port,
    stop_process,
    submit_approved_plan,
    wait_balance_stream,
    wait_controller_alive,
    wait_state,
)

from .conftest import screenshot
from .ui import click_and_confirm, login, open_job

BOB = SERVICE_TOKENS["bob"]  # approver and operator
TIMEOUT_MS = 30_000
CONTROLLER_UP_TIMEOUT_S = 60.0
#: The plan stands still this long (s): the twin's balance reaches the page at 10 Hz meanwhile.
STAND_S = 4
#: CoP samples the page must draw during the execution (10 Hz over STAND_S s gives about 40).
MIN_COP_POINTS = 10
#: Largest distance on the chart between the drawn CoP and the planned ZMP of a robot standing still, px
#: (the twin's CoP is its CoM's projection within millimetres; the chart draws the support polygon ~300 px wide).
MAX_COP_OFFSET_PX = 8.0


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, subprocess.Popen[bytes]]]:
    data = tmp_path_factory.mktemp("console-cop")
    port = free_port()
    srv = Server(data, workers=1, bridge_port=port).start()
    env = dict(os.environ, REGRASP_BRIDGE_LEASE_S=str(BRIDGE_LEASE_S),
               REGRASP_BRIDGE_WATCHDOG_TIMEOUT_S=str(BRIDGE_WATCHDOG_S),
               REGRASP_BRIDGE_TRUSTED_KEY=bridge_keys()["public"])
    log = open(data / "controller-sim.log", "ab")
    sim = subprocess.Popen([sys.executable, "-m", "service.cli.main", "controller-sim", "--robot-id", BRIDGE_ROBOT_ID,
                            "--listen", f"tcp/127.0.0.1:{port}", "--speed", "1", "--plant", "physics"],
                           cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        wait_controller_alive(srv, sim, CONTROLLER_UP_TIMEOUT_S)
        wait_balance_stream(srv, sim, CONTROLLER_UP_TIMEOUT_S)
        yield srv, sim
    finally:
        stop_process(sim)
        srv.stop()


def _points(polyline) -> list[tuple[float, float]]:
    return [tuple(map(float, p.split(","))) for p in (polyline.get_attribute("points") or "").split()]


def test_the_cop_trace_is_drawn_live_beside_the_planned_zmp(page, rig):
    srv, _ = rig
    job_id = submit_approved_plan(srv, {"scenario": f"stand-{STAND_S}"}, 60.0)
    login(page, srv.url, BOB)
    open_job(page, job_id, timeout_ms=TIMEOUT_MS)
    chart = page.locator("#com-chart svg")
    cop = page.locator('#com-chart polyline[data-role="cop-trace"]')
    expect(cop).to_have_count(1, timeout=TIMEOUT_MS)
    assert _points(cop) == []  # nothing measured before the dispatch
    click_and_confirm(page, "dispatch", timeout_ms=TIMEOUT_MS)
    expect(page.locator("#job-state")).to_have_text("executing", timeout=TIMEOUT_MS)
    # Live: CoP points arrive while the job is still executing.
    deadline = time.monotonic() + STAND_S + 20
    while int(chart.get_attribute("data-cop-samples") or 0) < 3 and time.monotonic() < deadline:
        time.sleep(0.1)
    with srv.client("bob") as bob:
        during = bob.get(f"/v1/jobs/{job_id}").json()["state"]
    assert int(chart.get_attribute("data-cop-samples") or 0) >= 3, "no CoP sample reached the page"
    assert during == "executing", f"the CoP came only after the execution ({during})"
    with srv.client("bob") as bob:
        done = wait_state(bob, job_id, {"succeeded", "aborted", "failed"}, 60.0)
    assert done["state"] == "succeeded", done["error"]
    expect(page.locator("#job-state")).to_have_text("succeeded", timeout=TIMEOUT_MS)
    points = _points(cop)
    assert len(points) >= MIN_COP_POINTS and int(chart.get_attribute("data-cop-samples")) == len(points)
    zmp = _points(page.locator('#com-chart polyline[data-role="zmp-trace"]'))
    assert zmp, "the planned ZMP is not drawn"
    zx, zy = zmp[0]  # the plan stands still: one planned ZMP
    worst = max(((x - zx) ** 2 + (y - zy) ** 2) ** 0.5 for x, y in points)
    assert worst <= MAX_COP_OFFSET_PX, f"the drawn CoP strays {worst:.1f} px from the planned ZMP"
    print(f"\nCoP points drawn during the execution: {len(points)}; farthest from the planned ZMP: {worst:.1f} px")
    screenshot(page, "console-cop-live")
    assert page.js_errors == []
