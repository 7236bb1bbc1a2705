"""Limits on connections, below the ASGI app: how many are open (overall and per client address) and how
long a client may take to send a request's headers.

Uvicorn has neither. Without them 4,000 connections that each sent half a header all stayed open (the
process's file handles went from 37 to 5,064): every one costs a file handle and memory until the client
leaves, and the application never sees them (it only sees complete headers). The guard is a subclass of
uvicorn's HTTP protocol, the one place that sees a connection from its first byte:

- a connection over ``max_connections`` open, or over ``max_per_client`` from one address, is answered
  ``503`` (``Retry-After``) and closed at once, before anything is parsed;
- the request's headers must be complete ``header_timeout_s`` after the connection opened or after the
  previous response on it; otherwise the connection is closed. The body's deadline is the ASGI
  middleware's (:class:`robobpp.server.limits.BodySizeLimit`), since only the application knows when a
  body is complete.

WebSocket connections (pull mode) are counted too: the transport stays in the table until it closes, even
after uvicorn hands it to its WebSocket protocol.

``/healthz`` has a reserve above ``max_connections``: a connection that arrives when the server is full is
held (:data:`HEALTH_RESERVE` at most, for :data:`HEALTH_PROBATION_S`) until its first bytes show what it asks;
``GET /healthz`` (or ``HEAD``) is served, anything else is answered 503 at once. Before, 2,000 half-sent
connections from 20 addresses filled the 1,000 slots and ``/healthz`` answered 503 for about 10 s (the
header deadline): an orchestrator would have restarted a server that was only under attack.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Any

REFUSAL = (
    b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: text/plain; charset=utf-8\r\nretry-after: 5\r\n"
    b"connection: close\r\ncontent-length: 33\r\n\r\ntoo many connections; retry later\n"
)


@dataclass(frozen=True, slots=True)
class ConnectionLimits:
    max_connections: int = 1000
    #: 0: no per-address limit (behind a reverse proxy every connection comes from the proxy's address).
    max_per_client: int = 160
    header_timeout_s: float = 10.0


#: Connections held above ``max_connections`` for a health check at once (see the module's docstring).
HEALTH_RESERVE = 16
#: How long a connection over the cap has to show that it asks for ``/healthz``.
HEALTH_PROBATION_S = 2.0
#: Request lines the reserve serves (followed by a space, ``?`` or end of the path).
HEALTH_REQUESTS = (b"GET /healthz", b"HEAD /healthz")


def _health_request(head: bytes) -> bool | None:
    """Whether ``head`` (a connection's first bytes) asks for ``/healthz``; ``None``: too short to tell."""
    for line in HEALTH_REQUESTS:
        if len(head) <= len(line):
            if line.startswith(head):
                return None
        elif head.startswith(line) and head[len(line) : len(line) + 1] in (b" ", b"?"):
            return True
    return False


class _Table:
    """Open transports of one server and their client addresses, and those held in the health reserve."""

    def __init__(self) -> None:
        self.open: dict[asyncio.BaseTransport, str] = {}
        self.reserve: set[asyncio.BaseTransport] = set()

    def prune(self) -> None:
        for transport in [t for t in self.open if t.is_closing()]:
            del self.open[transport]
        self.reserve = {t for t in self.reserve if not t.is_closing()}

    def count(self, address: str) -> tuple[int, int]:
        return len(self.open), sum(1 for a in self.open.values() if a == address)


def guarded_protocol(limits: ConnectionLimits) -> type[asyncio.Protocol]:
    """Uvicorn's HTTP protocol class with ``limits`` applied (pass as ``uvicorn.Config(http=...)``)."""
    from uvicorn.protocols.http.auto import AutoHTTPProtocol

    table = _Table()
    base: Any = AutoHTTPProtocol

    # uvicorn declares AutoHTTPProtocol as type[asyncio.Protocol], though both classes it may be (h11's,
    # httptools') have the on_response_complete hook used below: hence ``base: Any``.
    class Guarded(base):  # type: ignore[misc]
        _refused = False
        _header_timer: asyncio.TimerHandle | None = None
        #: Over the cap: the first bytes seen so far, until they show a health check (then ``None``).
        _probation: bytearray | None = None
        _reserved: asyncio.Transport | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:
            peer = transport.get_extra_info("peername")
            address = str(peer[0]) if isinstance(peer, tuple) and peer else ""
            table.prune()
            total, mine = table.count(address)
            if limits.max_per_client and mine >= limits.max_per_client:
                self._refuse(transport)
                return
            if total >= limits.max_connections:
                if len(table.reserve) >= HEALTH_RESERVE:
                    self._refuse(transport)
                    return
                # held until its first bytes show a health check (served) or anything else (refused)
                table.reserve.add(transport)
                self._reserved, self._probation = transport, bytearray()
                self._header_timer = self.loop.call_later(HEALTH_PROBATION_S, self._refuse, transport)
                return
            table.open[transport] = address
            super().connection_made(transport)
            self._arm()

        def _refuse(self, transport: asyncio.Transport) -> None:
            self._refused = True
            self._probation = None
            if not transport.is_closing():
                transport.write(REFUSAL)
                transport.close()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            table.open.pop(getattr(self, "transport", None), None)  # type: ignore[arg-type]
            if self._reserved is not None:
                table.reserve.discard(self._reserved)
            if not self._refused and self._probation is None:
                super().connection_lost(exc)

        def data_received(self, data: bytes) -> None:
            if self._refused:
                return
            if self._probation is not None:
                self._probation += data
                health = _health_request(bytes(self._probation))
                if health is None:
                    return
                assert self._reserved is not None
                if not health:
                    self._disarm()
                    self._refuse(self._reserved)
                    return
                data, self._probation = bytes(self._probation), None
                super().connection_made(self._reserved)
                self._arm()
            super().data_received(data)

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if self._reserved is not None:  # a health check over the cap: one answer, then the slot is free
                self.transport.close()
                return
            self._arm()  # the next request on this connection has its own header deadline

        def _arm(self) -> None:
            self._disarm()
            self._header_timer = self.loop.call_later(limits.header_timeout_s, self._headers_overdue)

        def _disarm(self) -> None:
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def _headers_overdue(self) -> None:
            self._header_timer = None
            transport = self.transport
            if transport.is_closing() or transport.get_protocol() is not self:  # closed, or now a WebSocket
                return
            cycle = self.cycle
            if cycle is not None and not cycle.response_complete:  # headers came: the request is the app's
                return
            transport.close()

    return Guarded


def server_config(settings: Any) -> dict[str, Any]:
    """The uvicorn options ``robobpp serve`` runs with (``settings``: :class:`robobpp.server.config.Settings`)."""
    limits = ConnectionLimits(
        max_connections=settings.max_connections,
        max_per_client=settings.max_connections_per_client,
        header_timeout_s=settings.header_timeout_s,
    )
    return {
        "http": guarded_protocol(limits),
        "timeout_keep_alive": 5,
        "backlog": 2048,
        # X-Forwarded-For (the address wrong tokens count against) only from the configured proxies
        "proxy_headers": True,
        "forwarded_allow_ips": settings.forwarded_allow_ips,
    }
