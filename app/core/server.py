"""The HTTP front: uvicorn's h11 protocol with deadlines on request headers and bodies, and the server's limits.

uvicorn closes a keep-alive connection that stays idle after a response
(``timeout_keep_alive``), but not one that never sends a request, nor one that sends its
headers a byte at a time (slowloris): both held a socket for ever, and 1,100 of them took
the service down. ``GuardedH11Protocol`` gives every request's headers ``header_timeout_s``
from the connection's first byte (or from its opening, for the first request) and closes
the connection when they are not complete by then.

Complete headers and then a body that never comes (or comes a byte at a time) held the
socket too: one such connection was still open at 90 s. A request's body must arrive whole
within ``body_timeout_s`` of its headers, with no pause over ``header_timeout_s`` between
two reads (time the server itself stops reading, while the app has not taken what came,
does not count); else the client is answered 408 and the connection closed.
"""

from __future__ import annotations

import asyncio
from functools import lru_cache
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol


@lru_cache(maxsize=1)
def _timeouts_s() -> tuple[float, float]:
    """``GSA_HEADER_TIMEOUT_S`` and ``GSA_BODY_TIMEOUT_S``, read once per process (each uvicorn worker loads the
    environment)."""
    from app.core.config import get_settings

    s = get_settings()
    return float(s.header_timeout_s), float(s.body_timeout_s)


def _header_timeout_s() -> float:
    return _timeouts_s()[0]


REQUEST_TIMEOUT = (
    b"HTTP/1.1 408 Request Timeout\r\ncontent-type: application/json\r\nconnection: close\r\ncontent-length: %d"
    b"\r\n\r\n%s"
)


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol, closing connections whose request headers do not arrive in time."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._header_timer: asyncio.TimerHandle | None = None
        self._body_timer: asyncio.TimerHandle | None = None
        self._body_deadline: float | None = None
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

    def _receiving_body(self) -> bool:
        return (
            self.cycle is not None
            and not self.cycle.response_complete
            and self.conn.their_state is h11.SEND_BODY
            and not self.transport.is_closing()
        )

    def _watch_body(self) -> None:
        """While a request's body arrives: the next read is due within the pause allowed, the whole by its deadline."""
        self._disarm_body_timer()
        if not self._receiving_body():
            self._body_deadline = None
            return
        now = self.loop.time()
        gap_s, whole_s = _timeouts_s()
        if self._body_deadline is None:
            self._body_deadline = now + whole_s
        self._body_timer = self.loop.call_at(min(self._body_deadline, now + gap_s), self._body_timeout)

    def _disarm_body_timer(self) -> None:
        if self._body_timer is not None:
            self._body_timer.cancel()
            self._body_timer = None

    def _body_timeout(self) -> None:
        self._body_timer = None
        if not self._receiving_body() or self.cycle is None:
            return
        late = self._body_deadline is not None and self.loop.time() >= self._body_deadline
        if self.flow.read_paused and not late:  # the server stopped reading (the app has not taken the body yet)
            self._watch_body()
            return
        gap_s, whole_s = _timeouts_s()
        why = (
            f"the request body did not arrive whole within {whole_s:g} s (GSA_BODY_TIMEOUT_S)"
            if late
            else f"no byte of the request body for {gap_s:g} s (GSA_HEADER_TIMEOUT_S)"
        )
        if not self.cycle.response_started:
            payload = b'{"detail": "%s"}' % why.encode()
            self.transport.write(REQUEST_TIMEOUT % (len(payload), payload))
            self.cycle.response_started = True
        # The app waiting for the body is told the client has gone; what it sends is dropped.
        self.cycle.disconnected = True
        self.cycle.message_event.set()
        self.transport.close()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        if self.cycle is not None and not self.cycle.response_complete:
            self._disarm_header_timer()  # the headers are complete: the request runs
            self._watch_body()
        elif not self.transport.is_closing():
            self._arm_header_timer()  # part of a request: its headers have until the deadline

    def on_response_complete(self) -> None:
        self._disarm_header_timer()  # idle again: uvicorn's keep-alive timeout takes over
        self._disarm_body_timer()
        self._body_deadline = None
        super().on_response_complete()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm_header_timer()
        self._disarm_body_timer()
        super().connection_lost(exc)


def uvicorn_limits(settings: Any) -> dict[str, Any]:
    """Return uvicorn's keyword arguments for the operator's timeouts and limits."""
    return {
        "http": "app.core.server:GuardedH11Protocol",  # by name: worker processes import it
        "timeout_keep_alive": settings.keep_alive_timeout_s,
        "timeout_graceful_shutdown": settings.shutdown_grace_s,
        "limit_concurrency": settings.max_connections,
    }


DESCRIPTORS_BESIDE_SOCKETS = 256  # files, the database, spooled uploads, the models


def raise_descriptor_limit(connections: int) -> int:
    """Raise the soft open-file limit toward the hard one, so ``connections`` sockets fit beside the files;
    return the soft limit now in force."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = connections + DESCRIPTORS_BESIDE_SOCKETS
    if soft != resource.RLIM_INFINITY and soft < want:
        new = want if hard == resource.RLIM_INFINITY else min(want, hard)
        resource.setrlimit(resource.RLIMIT_NOFILE, (new, hard))
        soft = new
    return int(soft)


def descriptor_warning(soft_limit: int, connections: int) -> str | None:
    """What to tell the operator when the open-file limit cannot hold ``connections`` sockets and the files.

    With the limit short, connections past it are not refused with a 503: accepting fails (and used to flood the
    log), and the service stops answering; 1,100 held connections did that at a limit of 1024.
    """
    import resource

    want = connections + DESCRIPTORS_BESIDE_SOCKETS
    if soft_limit == resource.RLIM_INFINITY or soft_limit >= want:
        return None
    return (
        f"the open-file limit is {soft_limit} (its hard limit) but GSA_MAX_CONNECTIONS={connections} needs {want}: "
        f"raise it (ulimit -Hn {want}, LimitNOFILE= in systemd, --ulimit nofile= in docker) or set "
        f"GSA_MAX_CONNECTIONS={max(16, soft_limit - DESCRIPTORS_BESIDE_SOCKETS)}"
    )
