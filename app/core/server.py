"""The HTTP front: uvicorn's h11 protocol with a deadline on request headers, and the server's limits.

uvicorn closes a keep-alive connection that stays idle after a response
(``timeout_keep_alive``), but not one that never sends a request, nor one that sends its
headers a byte at a time (slowloris): both held a socket for ever, and 1,100 of them took
the service down. ``GuardedH11Protocol`` gives every request's headers ``header_timeout_s``
from the connection's first byte (or from its opening, for the first request) and closes
the connection when they are not complete by then.
"""

from __future__ import annotations

import asyncio
from functools import lru_cache
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol


@lru_cache(maxsize=1)
def _header_timeout_s() -> float:
    """``GSA_HEADER_TIMEOUT_S``, read once per process (each uvicorn worker loads the environment)."""
    from app.core.config import get_settings

    return float(get_settings().header_timeout_s)


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol, closing connections whose request headers do not arrive in time."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._header_timer: asyncio.TimerHandle | None = None
        self._arm_header_timer()

    def _arm_header_timer(self) -> None:
        if self._header_timer is None:
            self._header_timer = self.loop.call_later(_header_timeout_s(), self._header_timeout)

    def _disarm_header_timer(self) -> None:
        if self._header_timer is not None:
            self._header_timer.cancel()
            self._header_timer = None

    def _header_timeout(self) -> None:
        self._header_timer = None
        if self.cycle is not None and not self.cycle.response_complete:
            return  # a request is being served: its headers arrived
        if not self.transport.is_closing():
            try:
                self.conn.send(h11.ConnectionClosed())
            except h11.LocalProtocolError:
                pass
            self.transport.close()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        if self.cycle is not None and not self.cycle.response_complete:
            self._disarm_header_timer()  # the headers are complete: the request runs
        elif not self.transport.is_closing():
            self._arm_header_timer()  # part of a request: its headers have until the deadline

    def on_response_complete(self) -> None:
        self._disarm_header_timer()  # idle again: uvicorn's keep-alive timeout takes over
        super().on_response_complete()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm_header_timer()
        super().connection_lost(exc)


def uvicorn_limits(settings: Any) -> dict[str, Any]:
    """Return uvicorn's keyword arguments for the operator's timeouts and limits."""
    return {
        "http": "app.core.server:GuardedH11Protocol",  # by name: worker processes import it
        "timeout_keep_alive": settings.keep_alive_timeout_s,
        "timeout_graceful_shutdown": settings.shutdown_grace_s,
        "limit_concurrency": settings.max_connections,
    }


def raise_descriptor_limit(connections: int) -> None:
    """Raise the soft open-file limit toward the hard one, so ``connections`` sockets fit beside the files."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = connections + 256
    if soft != resource.RLIM_INFINITY and soft < want:
        new = want if hard == resource.RLIM_INFINITY else min(want, hard)
        resource.setrlimit(resource.RLIMIT_NOFILE, (new, hard))
