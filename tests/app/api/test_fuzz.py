"""Property-based fuzzing of every route from the app's own OpenAPI schema (schemathesis), authenticated.

Each operation gets a mix of schema-valid and schema-invalid requests, ``GSA_FUZZ_EXAMPLES_PER_ROUTE`` of them (default 6
in the suite; ``make fuzz`` runs 5000 in all). Every response must be a non-5xx
whose status code, content type, headers and body are the ones the schema declares.
With ``GSA_FUZZ_REPORT=path`` the counts by route and status are written there.
"""

from __future__ import annotations

import atexit
import json
import os
from collections import Counter
from pathlib import Path

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.specs.openapi import checks as oa

from app.main import create_app
from tests.conftest import KEY_A

EXAMPLES = int(os.environ.get("GSA_FUZZ_EXAMPLES_PER_ROUTE", "6"))
REPORT = os.environ.get("GSA_FUZZ_REPORT")
# Small limits so that no generated request can tie the worker up (they are what an operator would set).
LIMITS = {
    "max_span_days": 1.0,
    "max_grid_points": 2_000,
    "max_batch_frames": 4,
    "max_upload_bytes": 300_000,
    "max_batch_bytes": 1_200_000,
    "max_image_side": 512,
    "max_page_size": 50,
    "job_workers": 0,  # jobs are queued and listed, never run: a generated data set may ask for a million frames
    "max_dataset_gb": 0.05,
}

# What a schema-valid request may be answered besides 2xx: 404 (an id that is well formed but not
# yours or not there), 413 (over the operator's upload limits, declared per route) and a 422 for a
# rule the schema cannot state (a cross-field rule such as dhp_min_km <= dhp_max_km, or physics:
# two orbits with no line of nodes, a perigee under 100 km, a span over the operator's limit).
# Those answer type "value_error"; any other 422 type (missing, *_type, greater_than, literal_error,
# extra_forbidden, ...) is a rule the validator has and the schema does not declare.
DOMAIN_ERROR_TYPES = {"value_error"}


@schemathesis.check
def positive_data_acceptance_told_apart(ctx, response, case):
    """schemathesis' positive_data_acceptance, with the refusals a schema cannot express told apart."""
    if case.meta is None or case.meta.generation.mode != GenerationMode.POSITIVE:
        return None
    status = response.status_code
    # 404 (no such record), 409 (a name already stored) and 413 depend on the state or the size, which
    # no schema states; each is a declared response of its route.
    if status < 300 or status in (404, 409, 413):
        return None
    if status == 422:
        errors = response.json().get("detail", [])
        undeclared = [e for e in errors if not isinstance(e, dict) or e.get("type") not in DOMAIN_ERROR_TYPES]
        if errors and not undeclared:
            return None
        raise AssertionError(
            f"a schema-valid request was refused by a rule the schema does not declare: {undeclared[:3]}"
        )
    raise AssertionError(f"a schema-valid request answered {status}: {response.text[:300]}")


@schemathesis.check
def negative_data_rejected_or_too_large(ctx, response, case):
    """schemathesis' negative_data_rejection, with a 413 counted as a refusal: a body over GSA_MAX_REQUEST_BYTES is
    refused by its size before its content is read (schemathesis' list of refusals leaves 413 out)."""
    if response.status_code == 413:
        return None
    return oa.negative_data_rejection(ctx, response, case)


CHECKS = [
    schemathesis.checks.not_a_server_error,
    positive_data_acceptance_told_apart,
    oa.status_code_conformance,
    oa.content_type_conformance,
    oa.response_headers_conformance,
    oa.response_schema_conformance,
    negative_data_rejected_or_too_large,
    oa.unsupported_method,
    oa.allow_header_conformance,
]
SEEN: Counter[tuple[str, int]] = Counter()
MODES: Counter[str] = Counter()


def _write_report() -> None:
    if REPORT and SEEN:
        rows = [{"operation": op, "status": st, "count": n} for (op, st), n in sorted(SEEN.items())]
        Path(REPORT).write_text(
            json.dumps({"examples_per_route": EXAMPLES, "modes": dict(MODES), "results": rows}, indent=2)
        )


atexit.register(_write_report)


@pytest.fixture(scope="module")
def fuzz_app(settings):
    s = settings.model_copy(update=LIMITS)
    app = create_app(s)
    with TestClient(app):  # runs start-up once
        yield app


def test_no_route_answers_5xx_or_off_schema(fuzz_app):
    schema = schemathesis.openapi.from_asgi("/openapi.json", fuzz_app)
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 13  # every route, health checks included
    failures = []
    for op in operations:

        @given(case=st.one_of(op.as_strategy(GenerationMode.POSITIVE), op.as_strategy(GenerationMode.NEGATIVE)))
        @settings(
            max_examples=EXAMPLES,
            deadline=None,
            derandomize=True,
            database=None,
            suppress_health_check=list(HealthCheck),
        )
        def fuzz(case):
            headers = dict(case.headers or {})
            negative = case.meta is not None and case.meta.generation.mode == GenerationMode.NEGATIVE
            if "X-API-Key" in headers or not negative:  # a negative case may leave the key out on purpose: 401
                headers["X-API-Key"] = KEY_A
            response = case.call(headers=headers)
            SEEN[(case.operation.label, response.status_code)] += 1
            MODES[case.meta.generation.mode.value if case.meta else "unknown"] += 1
            case.validate_response(response, checks=CHECKS)

        try:
            fuzz()
        except Exception as exc:  # collect every route's failure, then fail once naming them all
            failures.append(f"{op.label}: {str(exc)[:1500]}")
    assert not failures, "\n\n".join(failures)
    assert sum(n for (_, st), n in SEEN.items() if st >= 500) == 0


CONTROL_STRINGS = ["a\x00b", "\x00", "line\nbreak", "tab\there", "esc\x1b[31m", "del\x7f"]


def test_control_characters_in_every_string_parameter(fuzz_app):
    """Every path and query string parameter of every route, given NUL and other control characters:
    a 422 naming the parameter, never a 5xx (PostgreSQL cannot store NUL)."""
    from urllib.parse import quote

    spec = fuzz_app.openapi()
    client = TestClient(fuzz_app)
    sent = 0
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            params = [p for p in op.get("parameters", []) if p["in"] in ("path", "query")]
            for p in params:
                schema = p.get("schema", {})
                types = {schema.get("type")} | {s.get("type") for s in schema.get("anyOf", [])}
                if "string" not in types or schema.get("format") == "date-time":
                    continue
                for bad in CONTROL_STRINGS:
                    url = path
                    query = {}
                    for q in params:
                        if q["in"] == "path":
                            url = url.replace("{" + q["name"] + "}", quote(bad if q is p else "x", safe=""))
                    if p["in"] == "query":
                        query[p["name"]] = bad
                    r = client.request(method.upper(), url, params=query, headers={"X-API-Key": KEY_A})
                    sent += 1
                    assert r.status_code == 422, (method, url, p["name"], r.status_code, r.text[:300])
                    assert p["name"] in r.text
    assert sent >= 6 * len(CONTROL_STRINGS)
