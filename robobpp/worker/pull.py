"""The worker's side of pull mode: drive an episode through a participant's client via the server's relay.

:class:`PullTransport` has the interface of :class:`robobpp.client.wire.Connection`, so the episode runs
through the very :class:`~robobpp.client.remote.RemotePolicy` of push mode: the same messages, signing,
deadlines, size cap, validation of answers and termination reasons. Only the path differs: the worker
opens a WebSocket to the server (``/api/v1/pull/episodes/{id}``, authenticated by the episode's lease
token), the server pairs it with an idle connection of the submission's client and forwards frames
(:mod:`robobpp.client.frames`) both ways. Workers need to reach the server, never the participant, so
Celery workers on other machines work as they are (``ROBOBPP_PULL_RELAY_URL``).

When the client drops mid-episode the relay closes the worker's socket; the transport waits up to
``reconnect_s`` for a connection of the same submission, replays the episode's ``/reset`` and sends the
pending request again unchanged (its answer is signed for that very request; /reset is signed afresh). The episode goes on where it was: nothing is lost, and nothing is
counted twice because the result is still written once, under the lease.
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Callable
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI
from websockets.sync.client import ClientConnection, connect

from robobpp.client import frames, wire

if TYPE_CHECKING:
    import ssl

#: Close codes of the relay (robobpp.server.api.pull; the worker does not import the server).
GONE, REFUSED, NO_CLIENT, TOO_LARGE = 4001, 4003, 4004, 4009
RELAY_PATH = "/api/v1/pull/episodes/"


class NoClient(wire.ConnectFailed):
    """No client of the submission connected within the wait: hand the episode back for a retry."""


class _ClientGone(Exception):
    """The relay lost the client (or the relay itself went away): wait for a new pairing."""


class PullTransport:
    """Requests to a participant's client through the server's pull relay (one episode)."""

    def __init__(
        self,
        relay_url: str,
        episode_id: int,
        lease_token: str,
        *,
        wait_s: float = 30.0,
        reconnect_s: float = 30.0,
        connect_timeout_s: float = 5.0,
        max_frame_bytes: int = 64 * 1024 + frames.MAX_ENVELOPE,
        verify_tls: bool = True,
    ) -> None:
        parts = urlsplit(relay_url.rstrip("/"))
        if parts.scheme not in ("http", "https", "ws", "wss") or not parts.hostname:
            raise ValueError(f"ROBOBPP_PULL_RELAY_URL must be the server's http(s) URL, got {relay_url!r}")
        scheme = "wss" if parts.scheme in ("https", "wss") else "ws"
        self.url = f"{scheme}://{parts.netloc}{parts.path}{RELAY_PATH}{int(episode_id)}"
        self.lease_token = lease_token
        self.wait_s = wait_s
        self.reconnect_s = reconnect_s
        self.connect_timeout_s = connect_timeout_s
        self.max_frame_bytes = max_frame_bytes
        self.verify_tls = verify_tls
        #: Builds the headers of a request body (the policy's signing); replays are signed afresh.
        self.headers_for: Callable[[bytes], list[tuple[str, str]]] | None = None
        self.last_exchange_s: float | None = None
        self.pairings = 0  # how many client connections served this episode (reconnections show)
        self._ws: ClientConnection | None = None
        self._next_id = 0
        self._reset: tuple[str, str, bytes] | None = None

    @property
    def is_open(self) -> bool:
        return self._ws is not None

    def close(self) -> None:
        ws, self._ws = self._ws, None
        if ws is not None:
            ws.close()

    def pair(self, wait_s: float) -> None:
        """Open the relay socket and wait until the server pairs it with a client connection."""
        self.close()
        wait_s = max(0.0, wait_s)
        try:
            ws = connect(
                f"{self.url}?wait={wait_s:g}",
                additional_headers={"X-Robobpp-Lease": self.lease_token},
                open_timeout=self.connect_timeout_s,
                max_size=self.max_frame_bytes,
                compression=None,
                proxy=None,
                ping_interval=None,
                user_agent_header="robobpp-worker",
                ssl=self._tls(),
            )
        except (OSError, TimeoutError, InvalidHandshake, InvalidURI) as exc:
            raise wire.ConnectFailed(f"cannot reach the pull relay at {self.url}: {exc}") from None
        with contextlib.suppress(OSError):  # already closed by the relay: recv below says why
            ws.socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            hello = ws.recv(timeout=wait_s + self.connect_timeout_s)
        except TimeoutError:
            ws.close()
            raise NoClient(f"no client connected within {wait_s:g} s") from None
        except ConnectionClosed as exc:
            code, reason = (exc.rcvd.code, exc.rcvd.reason) if exc.rcvd else (None, "")
            if code == NO_CLIENT:
                raise NoClient(f"no client of this submission connected within {wait_s:g} s") from None
            raise wire.ConnectFailed(f"the pull relay refused the episode ({code}: {reason})") from None
        if hello != "paired":
            ws.close()
            raise wire.ConnectFailed(f"the pull relay said {str(hello)[:60]!r} instead of pairing")
        self._ws = ws
        self.pairings += 1

    def request(
        self, method: str, target: str, headers: list[tuple[str, str]], body: bytes, deadline: float, cap: int
    ) -> wire.Answer:
        if target.endswith("/reset"):
            self._reset = (method, target, body)
        if self._ws is None:
            self.pair(self.wait_s)
        budget = deadline - time.monotonic()
        try:
            return self._exchange(method, target, headers, body, deadline, cap)
        except _ClientGone:
            pass
        give_up = time.monotonic() + self.reconnect_s
        while True:
            try:
                self.pair(max(0.5, give_up - time.monotonic()))
                if self._reset is not None and not target.endswith("/reset"):
                    m, t, b = self._reset
                    again = self._exchange(m, t, self._sign(b, headers), b, time.monotonic() + budget, cap)
                    if again.status != 200:
                        raise wire.ConnectionBroke(
                            f"replaying /reset after the client came back: HTTP {again.status}"
                        )
                # The pending request goes again as it was: its answer is signed for this very request.
                return self._exchange(method, target, headers, body, time.monotonic() + budget, cap)
            except (_ClientGone, wire.ConnectFailed):
                if time.monotonic() >= give_up:
                    self.close()
                    raise wire.ConnectionBroke(
                        f"the pull client disconnected and did not come back within {self.reconnect_s:g} s"
                    ) from None
                time.sleep(0.2)

    def _sign(self, body: bytes, fallback: list[tuple[str, str]]) -> list[tuple[str, str]]:
        return self.headers_for(body) if self.headers_for is not None else fallback

    def _exchange(
        self, method: str, target: str, headers: list[tuple[str, str]], body: bytes, deadline: float, cap: int
    ) -> wire.Answer:
        ws = self._ws
        if ws is None:
            raise _ClientGone
        self._next_id += 1
        rid = self._next_id
        frame = frames.encode({"id": rid, "method": method, "path": target}, headers, body)
        sent = time.perf_counter()
        try:
            ws.send(frame)
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise wire.DeadlineExceeded
                data = ws.recv(timeout=left)
                if isinstance(data, str):
                    continue
                try:
                    answer = frames.decode(data)
                except ValueError as exc:
                    raise wire.ConnectionBroke(f"the pull client sent a malformed frame: {exc}") from None
                if answer.id != rid:
                    continue  # the late answer to a request given up on
                break
        except TimeoutError:
            raise wire.DeadlineExceeded from None
        except ConnectionClosed as exc:
            self._ws = None
            code = exc.rcvd.code if exc.rcvd else None
            if code == TOO_LARGE or (exc.sent is not None and exc.sent.code == 1009):
                raise wire.TooLarge("the client's answer passed the size cap") from None
            if code == REFUSED and exc.rcvd is not None:
                raise wire.ConnectionBroke(f"the pull relay ended the episode: {exc.rcvd.reason}") from None
            raise _ClientGone from None
        status = answer.envelope.get("status")
        if isinstance(status, bool) or not isinstance(status, int) or not 100 <= status <= 599:
            raise wire.ConnectionBroke("the pull client's answer has no valid 'status'")
        if len(answer.body) > cap:
            raise wire.TooLarge(f"{len(answer.body)} bytes")
        self.last_exchange_s = time.perf_counter() - sent
        return wire.Answer(status, {k.lower(): v for k, v in answer.headers}, answer.body)

    def _tls(self) -> ssl.SSLContext | None:
        if not self.url.startswith("wss://") or self.verify_tls:
            return None
        import ssl

        context = ssl.create_default_context()
        context.check_hostname = False
        context.verify_mode = ssl.CERT_NONE
        return context
