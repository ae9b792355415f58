"""The docs' response examples are what the service answers to the shipped example requests, today."""

import math
from datetime import datetime

import pytest

from app import openapi_examples as examples
from app.schemas import AccessPublic, CampaignPublic, EstimatePublic, PlanPublic, StationPublic

MODELS = {
    "plan": PlanPublic,
    "campaign": CampaignPublic,
    "access": AccessPublic,
    "estimate": EstimatePublic,
    "station": StationPublic,
}


def _instant(text):
    """The moment an ISO 8601 UTC string names, or None for other text."""
    if not (isinstance(text, str) and text.endswith("Z") and "T" in text):
        return None
    try:
        return datetime.fromisoformat(text[:-1] + "+00:00")
    except ValueError:
        return None


def _close(a, b, path="$"):
    """Equal structure and text; numbers within 1e-3 (another CPU's onnxruntime may differ in the last bits).

    Times within 1 ms: the planner finds a candidate's moment by bisection to 1e-4 s
    (planner.alignment.align_nodes' ``tol_s``), and where the bisection stops depends on the
    last bits of the propagation, which differ from CPU to CPU (30 us between an AVX2 and an
    AVX-512 machine).
    """
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), (path, sorted(a), sorted(b) if isinstance(b, dict) else b)
        for k in a:
            _close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, f"{path}[{k}]")
    elif isinstance(a, float) and isinstance(b, (int, float)):
        assert math.isclose(a, b, rel_tol=1e-4, abs_tol=1e-3), (path, a, b)
    elif _instant(a) is not None and _instant(b) is not None:
        assert abs((_instant(a) - _instant(b)).total_seconds()) <= 1e-3, (path, a, b)
    else:
        assert a == b, (path, a, b)


@pytest.mark.parametrize("name", examples.NAMES)
def test_each_example_is_a_valid_answer(name):
    body = examples.load(name)
    assert body, f"app/response_examples/{name}.json is missing: python -m app.openapi_examples writes it"
    MODELS[name].model_validate(body)


def test_the_examples_are_what_the_service_answers_now():
    fresh = examples.generate()
    for name in examples.NAMES:
        _close(examples.comparable(examples.load(name)), examples.comparable(fresh[name]), name)


def _without_nulls(body):
    if isinstance(body, dict):
        return {k: _without_nulls(v) for k, v in body.items() if v is not None}
    return [_without_nulls(v) for v in body] if isinstance(body, list) else body


def test_the_docs_carry_the_examples(client):
    spec = client.get("/openapi.json").json()["paths"]

    def example(path, method, status):
        return spec[path][method]["responses"][status]["content"]["application/json"]["example"]

    # FastAPI leaves null fields out of the document's examples; the rest is the stored answer.
    for path, method, status, name in (
        ("/v1/plans", "post", "201", "plan"),
        ("/v1/plans/{plan_id}", "get", "200", "plan"),
        ("/v1/access-windows", "post", "200", "access"),
        ("/v1/estimates", "post", "201", "estimate"),
        ("/v1/stations", "post", "201", "station"),
    ):
        assert example(path, method, status) == _without_nulls(examples.load(name)), path
