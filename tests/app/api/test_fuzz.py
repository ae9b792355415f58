"""Property-based fuzzing of every route from the app's own OpenAPI schema (schemathesis), authenticated.

Each operation gets a mix of schema-valid and schema-invalid requests, ``GSA_FUZZ_EXAMPLES_PER_ROUTE`` of them (default 6
in the suite; ``make fuzz`` runs 5000 in all). Every response must be a non-5xx
whose status code, content type, headers and body are the ones the schema declares.
With ``GSA_FUZZ_REPORT=path`` the counts by route and status are written there.
"""

from __future__ import annotations

import atexit
import io
import json
import os
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.specs.openapi import checks as oa

from app.main import create_app
from tests.conftest import KEY_A
from tests.utils.bodies import with_value

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


# --- extremes on purpose (issue 77): denormals, the largest floats, -0.0, one ulp either side of each bound ------

TINY, HUGE = 5e-324, 1.7976931348623157e308


def _numeric_fields(spec, schema, prefix=()):
    """Yield (path, is_integer, bounds) for every number or integer property of a JSON body schema, nested objects too."""
    comps = spec["components"]["schemas"]

    def resolve(s):
        while "$ref" in s:
            s = comps[s["$ref"].split("/")[-1]]
        return s

    schema = resolve(schema)
    for name, prop in schema.get("properties", {}).items():
        options = [resolve(p) for p in prop.get("anyOf", [prop])]
        for p in options:
            if p.get("type") in ("number", "integer"):
                bounds = {k: p[k] for k in ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum") if k in p}
                yield (*prefix, name), p["type"] == "integer", bounds
            elif p.get("type") == "object" or "properties" in p:
                yield from _numeric_fields(spec, p, (*prefix, name))


def _extremes(is_integer, bounds):
    if is_integer:
        return [-1, 2**63, *(b + d for b in bounds.values() for d in (-1, 1))]
    steps = (float(np.nextafter(b, t)) for b in bounds.values() for t in (-np.inf, np.inf))
    return [TINY, HUGE, -HUGE, -0.0, *steps]


def _outside(value, bounds):
    """Whether the schema itself refuses ``value`` (its stated bounds, or an integer out of 64 bits)."""
    return (
        value < bounds.get("minimum", -np.inf)
        or value <= bounds.get("exclusiveMinimum", -np.inf)
        or value > bounds.get("maximum", np.inf)
        or value >= bounds.get("exclusiveMaximum", np.inf)
        or abs(value) >= 2**63
    )


def _bases():
    from app.schemas import PAPER_EXAMPLE

    plan = with_value(with_value(PAPER_EXAMPLE, ("search", "duration_days"), 0.01), ("search", "step_km"), 5.0)
    station = {"name": "Extremes", "latitude_deg": 31.1, "longitude_deg": 121.3}
    return {
        ("/v1/plans", None): plan,
        ("/v1/access-windows", None): {
            "target": PAPER_EXAMPLE["target"],
            "ground_station": PAPER_EXAMPLE["ground_station"],
            "duration_days": 0.01,
        },
        ("/v1/stations", None): station,
        ("/v1/datasets", None): {"n": 2},
        ("/v1/model-sets/{target}/adaptations", "tiangong"): {},
        ("/v1/campaigns", ("duration_days", "dv_budget_m_s", "scene_span_days", "max_scenes")): {
            **{k: v for k, v in plan.items() if k != "search"},
            "duration_days": 0.01,
        },
    }


def test_numeric_fields_at_their_extremes_answer_4xx_naming_the_field(fuzz_app):
    """Every number of every JSON body given a denormal, the largest floats, -0.0 and one ulp either side of each
    bound the schema states: never a 5xx, and a 422 names the field (the plan's 5e-324 tracking rate was a 500)."""
    spec = fuzz_app.openapi()
    client = TestClient(fuzz_app)
    sent = refused = 0
    for (path, only), base in _bases().items():
        url = path.replace("{target}", only) if isinstance(only, str) else path
        schema = spec["paths"][path]["post"]["requestBody"]["content"]["application/json"]["schema"]
        for field, is_integer, bounds in _numeric_fields(spec, schema):
            if isinstance(only, tuple) and field not in [(f,) for f in only]:
                continue
            for value in _extremes(is_integer, bounds):
                r = client.post(url, json=with_value(base, field, value), headers={"X-API-Key": KEY_A})
                sent += 1
                assert r.status_code < 500, (url, field, value, r.text[:300])
                if _outside(value, bounds):  # what the schema refuses is refused, by the field's name
                    refused += 1
                    assert r.status_code == 422 and field[-1] in r.text, (url, field, value, r.text[:300])
    assert sent > 300 and refused > sent / 2


@pytest.mark.parametrize(
    "path, value",
    [
        (("search", "max_tracking_rate_deg_s"), TINY),
        (("search", "max_imaging_range_km"), TINY),
        (("search", "max_phase_angle_deg"), TINY),
        (("search", "max_miss_km"), TINY),
        (("observer_optics", "max_rate_deg_s"), TINY),
        (("observer_optics", "gsd_m"), TINY),
        (("ground_station", "max_range_km"), TINY),
        (("ground_station", "max_azimuth_rate_deg_s"), TINY),
    ],
)
def test_the_denormal_plan_request_and_its_siblings_are_422_naming_the_field(fuzz_app, path, value):
    """The request the schema fuzzer found (a 500 from ZeroDivisionError in standoff_window) and its siblings."""
    from app.schemas import PAPER_EXAMPLE

    r = TestClient(fuzz_app).post(
        "/v1/plans", json=with_value(PAPER_EXAMPLE, path, value), headers={"X-API-Key": KEY_A}
    )
    assert r.status_code == 422, r.text[:300]
    assert path[-1] in r.text


def test_denormal_cells_and_apertures_of_frames_are_422(fuzz_app):
    """Estimates' and passes' cell sizes and aperture, sent as form fields: a denormal is refused by name."""
    client = TestClient(fuzz_app)
    frame = io.BytesIO()
    np.save(frame, np.zeros((64, 64), np.float32))
    for url, fields in (
        ("/v1/estimates", {"range_cell_m": TINY}),
        ("/v1/estimates", {"cross_range_cell_m": TINY}),
        ("/v1/passes", {"aperture_deg": TINY}),
        ("/v1/passes", {"range_cell_m": TINY}),
    ):
        files = {"file" if url == "/v1/estimates" else "files": ("f.npy", frame.getvalue(), "application/octet-stream")}
        r = client.post(url, data={k: str(v) for k, v in fields.items()}, files=files, headers={"X-API-Key": KEY_A})
        assert r.status_code == 422, (url, fields, r.text[:300])
        assert next(iter(fields)) in r.text


def test_the_planner_refuses_the_same_values_by_name():
    """A library caller gets the planner's own refusal (PlannerError naming the field), not a ZeroDivisionError."""
    from planner.errors import PlannerError
    from planner.optics import ObserverOptics, standoff_window

    for name in ("max_rate_deg_s", "max_phase_angle_deg", "gsd_m"):
        with pytest.raises(PlannerError) as err:
            standoff_window(13.4, ObserverOptics(**{name: TINY}))
        assert err.value.field == name
