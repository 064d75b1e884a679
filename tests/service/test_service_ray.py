"""The Ray executor on a local Ray instance: same runner, progress and cancel as the local pool."""

from __future__ import annotations

import os
import time
import uuid
from pathlib import Path
from typing import Iterator

import pytest
from conftest import HERE, ROOT

from svc_test_handlers import HANDLERS

try:
    import ray
except Exception as exc:  # noqa: BLE001 - any import failure means: no Ray here
    pytest.skip(f"ray cannot be imported ({exc}); install the 'ray' extra to run these tests", allow_module_level=True)

from service.provenance import provenance  # noqa: E402
from service.runner import Runner  # noqa: E402
from service.settings import ServiceSettings  # noqa: E402
from service.store import JobStore, make_engine, migrate  # noqa: E402


@pytest.fixture(scope="module")
def ray_runner(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[JobStore, Runner]]:
    from service.executors.ray_executor import RayExecutor

    os.environ["PYTHONPATH"] = os.pathsep.join([str(HERE), str(ROOT), os.environ.get("PYTHONPATH", "")])
    data = tmp_path_factory.mktemp("ray")
    settings = ServiceSettings(data_dir=data, workers=2, executor="ray", handlers=HANDLERS, preload_robot=False,
                               check_scenario_names=False)
    engine = make_engine(settings.resolved_database_url)
    migrate(engine)
    store = JobStore(engine)
    executor = RayExecutor(settings)
    runner = Runner(store, executor, settings)
    runner.start()
    try:
        yield store, runner
    finally:
        runner.stop()
        executor.close()
        ray.shutdown()
        engine.dispose()


def _submit(store: JobStore, scenario: str) -> str:
    row, _ = store.create(job_id=str(uuid.uuid4()), kind="plan", submitter="ray", request={"scenario": scenario},
                          request_sha256=uuid.uuid4().hex, idempotency_key=None, provenance=provenance("hrp5p", None))
    return row["id"]


def _wait(store: JobStore, job_id: str, states: set[str], timeout: float = 60) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        row = store.get(job_id)
        if row and row["state"] in states:
            return row
        time.sleep(0.05)
    raise AssertionError(f"{job_id} stuck in {store.get(job_id)['state']}")


def test_ray_runs_jobs_with_progress(ray_runner: tuple[JobStore, Runner]) -> None:
    store, _ = ray_runner
    job_id = _submit(store, "busy-1.5")
    row = _wait(store, job_id, {"planned", "failed"}, timeout=120)
    assert row["state"] == "planned", row["error"]
    events = store.events_after(job_id)
    assert sum(e["kind"] == "progress" for e in events) >= 2
    assert any("ray actor" in (e["message"] or "") for e in events)
    assert store.result(job_id)["iterations"] > 0


def test_ray_cancel_polling_and_non_polling_within_1s(ray_runner: tuple[JobStore, Runner]) -> None:
    store, _ = ray_runner
    polite, stubborn = _submit(store, "busy-30"), _submit(store, "hang-30")
    _wait(store, polite, {"planning"})
    _wait(store, stubborn, {"planning"})
    time.sleep(0.5)
    t0 = time.monotonic()
    store.request_cancel(polite, "ray", None)
    store.request_cancel(stubborn, "ray", None)
    assert _wait(store, polite, {"canceled", "failed", "planned"}, 10)["state"] == "canceled"
    assert _wait(store, stubborn, {"canceled", "failed", "planned"}, 10)["state"] == "canceled"
    assert time.monotonic() - t0 < 1.0 + 0.5  # Ray actor kill adds a little over the local pool
    after = _submit(store, "quick")  # the killed actor was replaced
    assert _wait(store, after, {"planned", "failed"}, 60)["state"] == "planned"
