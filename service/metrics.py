"""Prometheus metrics: queue depth and jobs by state (read from the store at scrape time),
job durations and outcomes (observed by this process's runner), HTTP request latency."""

from __future__ import annotations

from typing import Iterable

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from .store.repo import JobStore

DURATION_BUCKETS = (0.1, 0.5, 1, 2, 5, 10, 30, 60, 120, 300, 600, 1800)
LATENCY_BUCKETS = (0.002, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5)


class StoreCollector(Collector):
    """Counts from the job store, so every replica reports the same truth."""

    def __init__(self, store: JobStore) -> None:
        self.store = store

    def collect(self) -> Iterable[Metric]:
        counts = self.store.count_by_state()
        depth = GaugeMetricFamily("regrasp_queue_depth", "Jobs waiting for a worker (state queued).")
        depth.add_metric([], sum(n for (_, s), n in counts.items() if s == "queued"))
        yield depth
        by_state = GaugeMetricFamily("regrasp_jobs", "Jobs in the store by kind and state.", labels=["kind", "state"])
        for (kind, state), n in sorted(counts.items()):
            by_state.add_metric([kind, state], n)
        yield by_state


class Metrics:
    def __init__(self, store: JobStore) -> None:
        self.registry = CollectorRegistry()
        self.registry.register(StoreCollector(store))
        self.job_duration = Histogram("regrasp_job_duration_seconds", "Planning time of finished jobs.",
                                      ["kind", "outcome"], buckets=DURATION_BUCKETS, registry=self.registry)
        self.job_outcomes = Counter("regrasp_job_outcomes", "Jobs finished by this process, by kind and outcome.",
                                    ["kind", "outcome"], registry=self.registry)
        self.http_latency = Histogram("regrasp_http_request_duration_seconds", "HTTP request latency.",
                                      ["method", "route", "status"], buckets=LATENCY_BUCKETS, registry=self.registry)

    def job_finished(self, kind: str, outcome: str, seconds: float) -> None:
        self.job_duration.labels(kind, outcome).observe(seconds)
        self.job_outcomes.labels(kind, outcome).inc()
