"""The service's shared objects (store, tokens, runner, bridge, ...), built once per app."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from typing import Any

from schemas.policy import SafetyPolicy, default_policy

from .api.auth import TokenStore
from .api.metrics import Metrics
from .audit.pump import AuditProcess
from .execution.bridge import Bridge, make_bridge
from .execution.dispatch import Executions
from .jobs.owners import LiveOwners
from .jobs.runner import Runner
from .settings import ServiceSettings
from .store import JobStore, make_engine, migrate
from .store.health import StorageHealth

log = logging.getLogger("regrasp.service")


@dataclass
class Service:
    settings: ServiceSettings
    store: JobStore
    tokens: TokenStore
    metrics: Metrics
    bridge: Bridge
    executions: Executions
    runner: Runner | None = None
    executor: Any = None
    auditor: AuditProcess | None = None
    #: The site's safety policy (the gate's floor and caps; comparisons are judged by it), read once at start.
    policy: SafetyPolicy = field(default_factory=default_policy)
    storage: StorageHealth | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def build(cls, settings: ServiceSettings, *, tokens: TokenStore | None = None, run_workers: bool = True,
              bridge: Bridge | None = None) -> "Service":
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        # One survey answer per task, shared by the workers' jobs (planner/survey_cache.py).
        os.environ.setdefault("REGRASP_SURVEY_CACHE_DIR", str((settings.data_dir / "survey-cache").resolve()))
        engine = make_engine(settings.resolved_database_url, pool_size=20)
        migrate(engine)
        store = JobStore(engine)
        metrics = Metrics(store)
        policy = settings.safety_policy()
        bridge = bridge or make_bridge(policy)
        owners = LiveOwners()
        storage = StorageHealth(settings.data_dir, min_free_bytes=settings.disk_min_free_bytes,
                                reserve_bytes=settings.disk_reserve_bytes)
        svc = cls(settings=settings, store=store, tokens=tokens or TokenStore.from_settings(settings),
                  metrics=metrics, bridge=bridge, executions=Executions(store, bridge, settings, owners), policy=policy,
                  storage=storage)
        if run_workers and settings.workers > 0:
            from .executors import make_executor

            svc.executor = make_executor(settings)
            svc.runner = Runner(store, svc.executor, settings, owners=owners, policy=policy, storage=storage)
        if settings.audit:
            svc.auditor = AuditProcess(settings.resolved_database_url, settings.audit_dir)
        return svc

    def start(self) -> None:
        if self.storage is not None:
            self.storage.start()
        if self.settings.metrics_port is not None:
            from prometheus_client import start_http_server

            server, _ = start_http_server(self.settings.metrics_port, addr=self.settings.metrics_host,
                                          registry=self.metrics.registry)
            self.extra["metrics_server"] = server
            log.info("metrics on http://%s:%d/metrics (no token)", self.settings.metrics_host, self.settings.metrics_port)
        if self.runner is not None:
            self.runner.start()
        if self.auditor is not None:
            self.auditor.start()

    def close(self) -> None:
        metrics_server = self.extra.pop("metrics_server", None)
        if metrics_server is not None:
            metrics_server.shutdown()
            metrics_server.server_close()
        if self.runner is not None:
            self.runner.stop()
        if self.executor is not None:
            self.executor.close()
        self.executions.close()
        try:
            self.bridge.close()
        except Exception:  # noqa: BLE001
            log.exception("closing the bridge failed")
        if self.auditor is not None:
            self.auditor.stop()
        self.store.engine.dispose()
