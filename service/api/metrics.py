"""Prometheus metrics of the planning service.

From the job store at scrape time, so every API replica reports the same truth,
including jobs planned by separate ``regrasp worker`` processes and jobs
finished before a restart: queue depth, jobs by state, and the planning time
(histogram) and outcome (counter) of every job whose planning ended, which the
runner that planned it (or recovery) writes to the job's row. In this process:
HTTP request latency.
"""

from __future__ import annotations

from typing import Iterable

from prometheus_client import CollectorRegistry, Histogram
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    Metric,
)
from prometheus_client.registry import Collector

from ..store.repo import JobStore

DURATION_BUCKETS = (0.1, 0.5, 1, 2, 5, 10, 30, 60, 120, 300, 600, 1800)
LATENCY_BUCKETS = (0.002, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5)


class StoreCollector(Collector):
    """Metrics read from the job store at each scrape."""

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
        stats = self.store.planning_stats(DURATION_BUCKETS)
        duration = HistogramMetricFamily("regrasp_job_duration_seconds",
                                         "Planning time of jobs whose planning ended, by kind and outcome (any runner).",
                                         labels=["kind", "outcome"])
        outcomes = CounterMetricFamily("regrasp_job_outcomes",
                                       "Jobs whose planning ended, by kind and outcome (any runner).",
                                       labels=["kind", "outcome"])
        for row in sorted(stats, key=lambda r: (r["kind"], r["outcome"])):
            labels = [row["kind"], row["outcome"]]
            buckets = [(str(float(b)), n) for b, n in zip(DURATION_BUCKETS, row["buckets"])]
            duration.add_metric(labels, buckets + [("+Inf", row["timed"])], sum_value=row["sum"])
            outcomes.add_metric(labels, row["count"])
        yield duration
        yield outcomes


class Metrics:
    def __init__(self, store: JobStore) -> None:
        self.registry = CollectorRegistry()
        self.registry.register(StoreCollector(store))
        self.http_latency = Histogram("regrasp_http_request_duration_seconds", "HTTP request latency.",
                                      ["method", "route", "status"], buckets=LATENCY_BUCKETS, registry=self.registry)
