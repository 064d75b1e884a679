"""``regrasp worker``: planning workers alone, against a shared job store."""

from __future__ import annotations

import os
import signal
import threading
from pathlib import Path

import click

from .common import console, fail, open_store_or_exit
from .serve import _settings_from_flags


@click.command()
@click.option("--data-dir", type=click.Path(path_type=Path), default=None, help="Embedded store directory (default ./var).")
@click.option("--database-url", default=None, help="SQLAlchemy URL of the shared store (PostgreSQL for several machines).")
@click.option("--workers", type=int, default=None, help="Worker processes (default 2).")
@click.option("--executor", type=click.Choice(["local", "ray"]), default=None)
@click.option("--ray-address", default=None)
@click.option("--config", "config", type=click.Path(path_type=Path, dir_okay=False), default=None)
@click.option("--init-store", is_flag=True, default=False,
              help="Start a new store when the existing file is empty or damaged (it is moved aside, not deleted).")
@click.option("--log-level", default="info", type=click.Choice(["debug", "info", "warning", "error"]))
def worker(data_dir: Path | None, database_url: str | None, workers: int | None, executor: str | None,
           ray_address: str | None, config: Path | None, init_store: bool, log_level: str) -> None:
    """Claim and run queued jobs from the job store until stopped (SIGINT/SIGTERM)."""
    import logging

    from service.executors import make_executor
    from service.jobs.runner import Runner
    from service.store import JobStore, make_engine, migrate

    settings = _settings_from_flags(config, data_dir=data_dir, database_url=database_url, workers=workers,
                                    executor=executor, ray_address=ray_address)
    if settings.workers < 1:
        fail("regrasp worker needs --workers 1 or more")
    from schemas.policy import POLICY_ENV, PolicyError

    try:  # read before anything starts: a bad file is one line and exit 2, never a traceback in a worker
        site_policy = settings.safety_policy()
    except PolicyError as exc:
        fail(str(exc))
    if settings.policy is not None:  # the workers' processes (risk card's gate dry run) read the same file
        os.environ[POLICY_ENV] = str(Path(settings.policy).resolve())
    logging.basicConfig(level=log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    open_store_or_exit(settings.resolved_database_url, init_store or settings.init_store)
    engine = make_engine(settings.resolved_database_url)
    migrate(engine)
    store = JobStore(engine)
    executor_obj = make_executor(settings)
    runner = Runner(store, executor_obj, settings, policy=site_policy)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    runner.start()
    console.print(f"worker {runner.owner}: {settings.workers} {settings.executor} worker(s) on "
                  f"{settings.resolved_database_url.split('://')[0]} store", highlight=False)
    try:
        done.wait()
    finally:
        runner.stop()
        executor_obj.close()
        engine.dispose()
