"""Prometheus metrics (``GET /metrics``): requests by route and status, their latency, and the planning work.

One registry per app (tests build many apps in one process). With several workers each process answers for
itself: scrape each worker, or run one (prometheus-client's multiprocess mode is not set up here).
"""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Histogram

LATENCY_BUCKETS_S = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0)
# HTTP's methods (RFC 9110, and PATCH): any other method a client sends is counted as "other", so a label value never
# comes from the request (1,000 requests with 10 kB methods made a scrape 165 MB, until restart).
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS", "CONNECT", "TRACE"})
WORK_BUCKETS_S = (0.1, 0.25, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0, 15.0, 30.0, 60.0, 120.0)


class Metrics:
    """The service's metrics, registered in their own registry."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter(
            "gsa_http_requests_total",
            "HTTP requests answered, by method, route template and status",
            ("method", "route", "status"),
            registry=self.registry,
        )
        self.latency = Histogram(
            "gsa_http_request_duration_seconds",
            "time from a request's first byte to its answer, by method and route template",
            ("method", "route"),
            buckets=LATENCY_BUCKETS_S,
            registry=self.registry,
        )
        self.work = Histogram(
            "gsa_work_duration_seconds",
            "time a plan, a campaign, an estimate upload or a pass took, by kind (stored ones only)",
            ("kind",),
            buckets=WORK_BUCKETS_S,
            registry=self.registry,
        )
        self.frames = Counter(
            "gsa_frames_estimated_total",
            "ISAR frames estimated (single uploads, batches and passes)",
            registry=self.registry,
        )

    def request(self, method: str, route: str, status: int, seconds: float) -> None:
        method = method if method in METHODS else "other"
        self.requests.labels(method, route, str(status)).inc()
        self.latency.labels(method, route).observe(seconds)
