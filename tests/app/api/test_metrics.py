"""GET /metrics: Prometheus' text format, read back by prometheus-client's own parser (the format's reference
implementation), counting what the service was asked and how long it took."""

import numpy as np
from prometheus_client.parser import text_string_to_metric_families

from app.schemas import PAPER_EXAMPLE
from tests.conftest import KEY_A

A = {"X-API-Key": KEY_A}


def _samples(client):
    r = client.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
    return [s for family in text_string_to_metric_families(r.text) for s in family.samples]


def _value(samples, name, **labels):
    return sum(s.value for s in samples if s.name == name and all(s.labels.get(k) == v for k, v in labels.items()))


def test_metrics_count_requests_by_route_template_and_time_the_work(client):
    before = _samples(client)
    plan = client.post("/v1/plans", json=PAPER_EXAMPLE, headers=A)
    assert plan.status_code == 201
    for _ in range(3):
        assert client.get(f"/v1/plans/{plan.json()['id']}", headers=A).status_code == 200
    assert client.get("/v1/plans/no-such-plan", headers=A).status_code == 404
    buf = __import__("io").BytesIO()
    np.save(buf, np.random.default_rng(0).random((64, 64)))
    assert client.post("/v1/estimates", files={"file": ("f.npy", buf.getvalue())}, headers=A).status_code == 201
    after = _samples(client)

    def grew(name, **labels):
        return _value(after, name, **labels) - _value(before, name, **labels)

    total = "gsa_http_requests_total"
    # One series per route template, not per id: the three reads and the 404 share "/v1/plans/{plan_id}".
    assert grew(total, method="GET", route="/v1/plans/{plan_id}", status="200") == 3
    assert grew(total, method="GET", route="/v1/plans/{plan_id}", status="404") == 1
    assert grew(total, method="POST", route="/v1/plans", status="201") == 1
    assert not any(s.labels.get("route", "").endswith(plan.json()["id"]) for s in after)
    latency = "gsa_http_request_duration_seconds_count"
    assert grew(latency, method="GET", route="/v1/plans/{plan_id}") == 4
    assert grew("gsa_work_duration_seconds_count", kind="plan") == 1
    assert grew("gsa_work_duration_seconds_sum", kind="plan") > 0.1  # a plan takes most of a second at least
    assert grew("gsa_work_duration_seconds_count", kind="estimate") == 1
    assert grew("gsa_frames_estimated_total") == 1
    assert client.get("/metrics").status_code == 200  # no key needed, like /healthz


def test_a_method_no_http_names_is_counted_as_other(client):
    """A label value never comes from the request: 20 requests with 10 kB methods are one "other" series, and the
    scrape does not carry the method."""
    before = _samples(client)
    for k in range(20):
        r = client.request("X" * 10_000 + str(k), "/v1/plans", headers=A)
        assert r.status_code in (400, 404, 405)
    r = client.get("/metrics")
    assert "XXXXXXXX" not in r.text and len(r.text) < 200_000
    after = _samples(client)
    grew = _value(after, "gsa_http_requests_total", method="other") - _value(
        before, "gsa_http_requests_total", method="other"
    )
    assert grew == 20
