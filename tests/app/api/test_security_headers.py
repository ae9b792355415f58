"""Security headers: the console runs only its own script and styles, nothing frames the service, the API's
answers are not cached, and no response is content-sniffed (MDN's header semantics are the reference)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from app.core.headers import CONSOLE_CSP
from tests.conftest import KEY_A

A = {"X-API-Key": KEY_A}
CONSOLE = Path(__file__).resolve().parents[3] / "app" / "console"


@pytest.fixture(scope="module")
def backend() -> str:
    """What this module tests does not depend on the database: SQLite alone (the suite's time is kept for the rest)."""
    return "sqlite"


def _directives(csp: str) -> dict[str, list[str]]:
    return {d.split()[0]: d.split()[1:] for d in (p.strip() for p in csp.split(";")) if d}


def test_every_kind_of_response_carries_the_headers(client):
    for path, headers in (
        ("/console/", {}),
        ("/console/console.js", {}),
        ("/v1/plans", A),
        ("/v1/plans", {}),  # a 401
        ("/v1/plans/no-such-plan", A),  # a 404
        ("/healthz", {}),
        ("/docs", {}),
    ):
        r = client.get(path, headers=headers)
        assert r.headers["x-content-type-options"] == "nosniff", path
        assert r.headers["referrer-policy"] == "no-referrer", path
        assert r.headers["x-frame-options"] == "DENY", path
        assert _directives(r.headers["content-security-policy"])["frame-ancestors"] == ["'none'"], path
        if path.startswith("/v1"):
            assert r.headers["cache-control"] == "no-store", path


def test_a_refused_oversized_body_carries_them_too(client, settings):
    r = client.post(
        "/v1/plans", content=b"x" * (settings.max_request_bytes + 1), headers={**A, "Content-Type": "application/json"}
    )
    assert r.status_code == 413 and r.headers["x-content-type-options"] == "nosniff"


def test_the_console_policy_allows_no_inline_script_or_style_and_the_console_needs_none(client):
    csp = _directives(client.get("/console/").headers["content-security-policy"])
    assert csp == _directives(CONSOLE_CSP)
    for directive in ("script-src", "style-src", "default-src"):
        assert csp[directive] == ["'self'"], directive
    assert csp["object-src"] == ["'none'"] and csp["base-uri"] == ["'none'"]
    html = (CONSOLE / "index.html").read_text()
    js = (CONSOLE / "console.js").read_text()
    scripts = re.findall(r"<script\b([^>]*)>", html)
    assert scripts and all("src=" in attrs for attrs in scripts), scripts  # no inline script
    for text in (html, js):
        assert not re.search(r"<style\b", text)  # no inline style sheet
        assert not re.search(r"\sstyle\s*=", text)  # no style attribute
        assert not re.search(r"\son[a-z]+\s*=\s*[\"']", text)  # no inline event handler
        assert "javascript:" not in text
