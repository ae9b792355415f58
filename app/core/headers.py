"""Security headers on every response: what a browser may do with the service's pages and answers.

- everywhere: ``X-Content-Type-Options: nosniff`` (an uploaded frame served back as a PNG is never read as HTML),
  ``Referrer-Policy: no-referrer``, and no framing (``X-Frame-Options: DENY``, CSP ``frame-ancestors 'none'``);
- the console (``/console/``): a Content-Security-Policy that allows only the console's own script, styles and
  the API (no inline script or style, nothing from elsewhere), so an injected string cannot run;
- the API (``/v1``): ``Cache-Control: no-store`` (answers are an operator's own data; no shared cache keeps them).

The API docs (``/docs``, ``/redoc``) start Swagger UI and ReDoc with an inline script of their own: they get
the framing rule, not the console's script rule.
"""

from __future__ import annotations

from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

CONSOLE_CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; connect-src 'self'; "
    "object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
)
OTHER_CSP = "frame-ancestors 'none'"
ALWAYS = {
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
}


def headers_for(path: str) -> dict[str, str]:
    """The security headers of a response to ``path``."""
    out = dict(ALWAYS)
    out["Content-Security-Policy"] = CONSOLE_CSP if path.startswith("/console") else OTHER_CSP
    if path.startswith("/v1/") or path == "/v1":
        out["Cache-Control"] = "no-store"
    return out


class SecurityHeadersMiddleware:
    """Adds ``headers_for(path)`` to every HTTP response (a header the route set itself is kept)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        extra = headers_for(str(scope.get("path", "")))

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                for k, v in extra.items():
                    if k not in headers:
                        headers[k] = v
            await send(message)

        await self.app(scope, receive, send_with_headers)
