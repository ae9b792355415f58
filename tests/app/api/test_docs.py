"""The API docs work with no network: /docs and /redoc reference only files the app itself serves."""

from __future__ import annotations

import re

import pytest


@pytest.mark.parametrize("page", ["/docs", "/redoc"])
def test_docs_pages_load_every_asset_from_the_app(client, page):
    r = client.get(page)
    assert r.status_code == 200 and "text/html" in r.headers["content-type"]
    refs = re.findall(r"""(?:src|href)=["']([^"']+)["']|url:\s*["']([^"']+)["']|spec-url=["']([^"']+)["']""", r.text)
    urls = {u for group in refs for u in group if u}
    assert not [u for u in urls if re.match(r"^(https?:)?//", u)], urls  # nothing from another host
    assert any(u.endswith(".js") for u in urls)
    for u in urls:
        asset = client.get(u)
        assert asset.status_code == 200, u
        assert len(asset.content) > 100, u
    assert "/openapi.json" in r.text


def test_the_landing_page_links_docs_and_health(client):
    r = client.get("/")
    assert r.status_code == 200 and "text/html" in r.headers["content-type"]
    links = re.findall(r'href="([^"]+)"', r.text)
    assert {"/docs", "/redoc", "/healthz", "/readyz"} <= set(links)
    for link in links:
        assert client.get(link).status_code == 200, link


def test_every_estimate_form_field_is_described(client):
    spec = client.get("/openapi.json").json()
    for name, schema in spec["components"]["schemas"].items():
        if name.startswith("Body_create_estimate"):
            for field in ("resample", "plan_id", "observed_at", "normalised"):
                if field in schema["properties"]:
                    assert schema["properties"][field].get("description"), (name, field)


def test_every_field_of_every_schema_is_described(client):
    """Each request and response field says what it is (FastAPI's own validation-error schemas aside)."""
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    bare = [
        f"{name}.{prop}"
        for name, comp in schemas.items()
        if name not in ("HTTPValidationError", "ValidationError")
        for prop, sch in comp.get("properties", {}).items()
        if not sch.get("description")
    ]
    assert not bare, bare
    assert len(schemas) > 30
