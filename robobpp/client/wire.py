"""One keep-alive HTTP/1.1 connection with a hard deadline on every exchange (h11 over a plain socket).

Why not httpx here: its timeouts bound each socket operation, so a server that drips one byte per
second never trips them, and enforcing a whole-exchange deadline around it costs an event loop or a
thread hop plus about a millisecond of CPU per request. Driving h11 (the HTTP/1.1 engine httpx itself
uses) directly lets every ``recv`` wait only for what is left of the deadline, stop reading at the
size cap, and costs a few tens of microseconds.
"""

from __future__ import annotations

import socket
import ssl
import time
from dataclasses import dataclass

import h11

#: Most bytes of status line + headers accepted (h11 refuses more: a header flood ends there).
MAX_HEAD_BYTES = 16 * 1024


class DeadlineExceeded(Exception):
    """The exchange did not finish before its deadline."""


class ConnectTimedOut(DeadlineExceeded):
    """No connection within the connect timeout."""


class ConnectFailed(Exception):
    """No connection could be opened (refused, unreachable, TLS handshake failed)."""


class ConnectionBroke(Exception):
    """The peer closed the connection or sent something that is not HTTP/1.1."""


class _Stale(ConnectionBroke):
    """A kept-alive connection turned out closed before any answer byte: safe to retry once, fresh."""


class TooLarge(Exception):
    """The answer passed the size cap; reading stopped there."""


@dataclass(frozen=True, slots=True)
class Answer:
    status: int
    headers: dict[str, str]
    body: bytes


class Connection:
    """A client connection to one origin, reopened transparently when the server closed it."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        connect_to: str | None = None,
        tls: bool = False,
        verify_tls: bool = True,
        connect_timeout_s: float = 5.0,
    ) -> None:
        self.host = host  # for Host and TLS server name
        self.port = port
        self.address = connect_to or host  # the pinned IP, when the caller resolved and vetted it
        self.connect_timeout_s = connect_timeout_s
        self._tls: ssl.SSLContext | None = None
        if tls:
            self._tls = ssl.create_default_context()
            if not verify_tls:
                self._tls.check_hostname = False
                self._tls.verify_mode = ssl.CERT_NONE
        self._sock: socket.socket | None = None
        self._h11: h11.Connection | None = None
        self.opened = 0  # connections opened so far (keep-alive shows as 1)
        #: Seconds from sending the last request to its complete answer (the round trip, no connect).
        self.last_exchange_s: float | None = None

    def _remaining(self, deadline: float) -> float:
        left = deadline - time.monotonic()
        if left <= 0:
            raise DeadlineExceeded
        return left

    def _open(self, deadline: float) -> None:
        timeout = min(self.connect_timeout_s, self._remaining(deadline))
        try:
            sock = socket.create_connection((self.address, self.port), timeout=timeout)
        except TimeoutError:
            raise ConnectTimedOut from None
        except OSError as exc:
            raise ConnectFailed(str(exc) or type(exc).__name__) from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # no Nagle delay on small requests
        if self._tls is not None:
            try:
                sock.settimeout(self._remaining(deadline))
                sock = self._tls.wrap_socket(sock, server_hostname=self.host)
            except TimeoutError:
                sock.close()
                raise DeadlineExceeded from None
            except (OSError, ssl.SSLError) as exc:
                sock.close()
                raise ConnectFailed(f"TLS handshake failed: {exc}") from None
        self._sock = sock
        self._h11 = h11.Connection(h11.CLIENT, max_incomplete_event_size=MAX_HEAD_BYTES)
        self.opened += 1

    @property
    def is_open(self) -> bool:
        return self._sock is not None

    def close(self) -> None:
        sock, self._sock, self._h11 = self._sock, None, None
        if sock is not None:
            sock.close()

    def request(
        self, method: str, target: str, headers: list[tuple[str, str]], body: bytes, deadline: float, cap: int
    ) -> Answer:
        """Send one request and read its whole answer before ``deadline`` (``time.monotonic``)."""
        try:
            return self._request(method, target, headers, body, deadline, cap)
        except _Stale:
            self.close()  # the server closed the idle connection: retry once on a fresh one
        except BaseException:
            self.close()
            raise
        try:
            return self._request(method, target, headers, body, deadline, cap)
        except BaseException:
            self.close()
            raise

    def _request(
        self, method: str, target: str, headers: list[tuple[str, str]], body: bytes, deadline: float, cap: int
    ) -> Answer:
        reused = self._sock is not None
        if not reused:
            self._open(deadline)
        broke = _Stale if reused else ConnectionBroke
        assert self._sock is not None and self._h11 is not None
        sock, conn = self._sock, self._h11
        host = self.host if ":" not in self.host else f"[{self.host}]"
        default_port = 443 if self._tls is not None else 80
        all_headers = [("Host", host if self.port == default_port else f"{host}:{self.port}"), *headers]
        all_headers.append(("Content-Length", str(len(body))))
        try:
            data = conn.send(h11.Request(method=method, target=target, headers=all_headers))
            data += conn.send(h11.Data(data=body)) if body else b""
            data += conn.send(h11.EndOfMessage())
        except h11.LocalProtocolError as exc:
            raise ValueError(f"cannot send request: {exc}") from None
        sent_at = time.perf_counter()
        try:
            sock.settimeout(self._remaining(deadline))
            sock.sendall(data)
        except TimeoutError:
            raise DeadlineExceeded from None
        except OSError as exc:
            raise broke(f"sending failed: {exc}") from None
        status, answer_headers, chunks, size = 0, {}, [], 0
        while True:
            try:
                event = conn.next_event()
            except h11.RemoteProtocolError as exc:
                raise ConnectionBroke(f"the answer is not valid HTTP/1.1 ({exc})") from None
            if event is h11.NEED_DATA:
                try:
                    sock.settimeout(self._remaining(deadline))
                    received = sock.recv(65536)
                except TimeoutError:
                    raise DeadlineExceeded from None
                except OSError as exc:
                    raise broke(f"reading failed: {exc}") from None
                if received:
                    broke = ConnectionBroke  # the server answered something: never retry past this point
                elif conn.their_state is h11.SEND_RESPONSE:
                    raise broke("the server closed the connection without an answer")
                conn.receive_data(received)
                continue
            if isinstance(event, h11.Response):
                status = event.status_code
                answer_headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in event.headers}
                declared = answer_headers.get("content-length", "")
                if declared.isdigit() and int(declared) > cap:
                    raise TooLarge(f"Content-Length {declared}")
            elif isinstance(event, h11.InformationalResponse):
                continue
            elif isinstance(event, h11.Data):
                size += len(event.data)
                if size > cap:
                    raise TooLarge(f"more than {size} bytes sent")
                chunks.append(bytes(event.data))
            elif isinstance(event, h11.EndOfMessage):
                break
            elif isinstance(event, h11.ConnectionClosed):
                raise ConnectionBroke("the server closed the connection in the middle of the answer")
        self.last_exchange_s = time.perf_counter() - sent_at
        if conn.our_state is h11.DONE and conn.their_state is h11.DONE:
            conn.start_next_cycle()  # keep-alive
        else:
            self.close()
        return Answer(status, answer_headers, b"".join(chunks))
