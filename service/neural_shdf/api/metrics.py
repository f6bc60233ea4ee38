"""Prometheus metrics of one app instance (own registry, so several apps can coexist).

With several uvicorn workers, ``neural-shdf serve`` sets ``PROMETHEUS_MULTIPROC_DIR``
(prometheus-client's multiprocess mode): every worker writes its samples there and
``/metrics`` on any worker reports the sum over all of them.
"""

from __future__ import annotations

import os
import time

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    generate_latest,
    multiprocess,
)
from prometheus_client.exposition import CONTENT_TYPE_LATEST
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["CONTENT_TYPE_LATEST", "Metrics", "RequestMetricsMiddleware"]

_LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120)


class Metrics:
    """Counters and histograms the service exports at ``/metrics``."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        r = self.registry
        self.requests = Counter(
            "neural_shdf_http_requests", "HTTP requests.", ["method", "route", "status"], registry=r
        )
        self.request_seconds = Histogram(
            "neural_shdf_http_request_seconds",
            "HTTP request latency.",
            ["route"],
            buckets=_LATENCY_BUCKETS,
            registry=r,
        )
        self.shdf_computations = Counter(
            "neural_shdf_shdf_computations", "ShDF computations run.", ["method"], registry=r
        )
        self.shdf_seconds = Histogram(
            "neural_shdf_shdf_seconds",
            "ShDF computation time.",
            ["method"],
            buckets=_LATENCY_BUCKETS,
            registry=r,
        )
        self.segmentations = Counter(
            "neural_shdf_segmentations", "Segmentations (partitioning) run.", registry=r
        )
        self.segment_seconds = Histogram(
            "neural_shdf_segment_seconds",
            "Segmentation time.",
            buckets=_LATENCY_BUCKETS,
            registry=r,
        )
        self.cache_hits = Counter("neural_shdf_cache_hits", "Cache hits.", ["kind"], registry=r)
        self.cache_misses = Counter(
            "neural_shdf_cache_misses", "Cache misses.", ["kind"], registry=r
        )
        self.cache_corrupt = Counter(
            "neural_shdf_cache_corrupt_entries", "Corrupt cache entries dropped.", registry=r
        )
        self.cache_errors = Counter(
            "neural_shdf_cache_errors",
            "Cache backend errors (degraded to computing).",
            registry=r,
        )
        self.cache_degraded = Gauge(
            "neural_shdf_cache_degraded",
            "1 while Redis is unreachable and the local disk cache serves instead.",
            registry=r,
            multiprocess_mode="livemax",
        )
        self.jobs_rerun = Counter(
            "neural_shdf_jobs_rerun",
            "Jobs re-run because the worker running them stopped.",
            registry=r,
        )
        self.computations_cancelled = Counter(
            "neural_shdf_computations_cancelled",
            "Computations stopped at a checkpoint because every client waiting for them "
            "had disconnected.",
            registry=r,
        )
        self.jobs_running = Gauge(
            "neural_shdf_jobs_running",
            "Jobs running (summed over live workers).",
            registry=r,
            multiprocess_mode="livesum",
        )

    def count_cache(self, kind: str, *, hit: bool) -> None:
        """One cache lookup of ``kind`` (mesh, shdf, segmentation), hit or miss."""
        (self.cache_hits if hit else self.cache_misses).labels(kind).inc()

    def value(self, name: str, labels: dict[str, str] | None = None) -> float:
        """Current value of a sample (0 when absent); used by tests and health checks."""
        return self.registry.get_sample_value(name, labels or {}) or 0.0

    def export(self) -> bytes:
        """The text exposition: this app's registry, or all workers' in multiprocess mode."""
        if os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
            registry = CollectorRegistry()
            multiprocess.MultiProcessCollector(registry)
            return generate_latest(registry)
        return generate_latest(self.registry)


class RequestMetricsMiddleware:
    """Counts requests and their latency per route template (never per raw path)."""

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status = 500

        async def send_wrapper(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            route = scope.get("route")
            template = getattr(route, "path", None) or "unmatched"
            self.metrics.requests.labels(scope.get("method", ""), template, str(status)).inc()
            self.metrics.request_seconds.labels(template).observe(time.perf_counter() - start)
