"""Pull mode, the participant's side: connect a policy *out* to an evaluation server (``robobpp connect``).

For a policy that cannot listen on a public URL (a university NAT, a firewall, a laptop): the client
opens outbound WebSocket connections to the server (``/api/v1/pull/connect``), and the server's workers
drive episodes through them with the very messages of push mode. Each request is answered by the same
app :func:`robobpp.client.serve.create_policy_app` builds, called in-process, so validation, signing
and error answers are those of ``robobpp policy serve``, byte for byte. Echo probes (the evaluator's
network estimate) are answered here at once, without the policy.

A dropped connection is reopened with backoff; the worker waiting on the other side resumes the episode
on the new connection. ``parallel=N`` opens N connections, so N episodes run at once (with a policy
class, each connection gets its own instance; one instance is shared under a lock). The call returns
when the submission has finished.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import socket
import threading
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlsplit

from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI
from websockets.sync.client import connect as ws_connect

from robobpp import __version__
from robobpp.client import frames
from robobpp.client.api import FINISHED, ServerClient, ServerError
from robobpp.schemas import SubmissionPublic
from robobpp.vocabulary import BoardTrack

log = logging.getLogger("robobpp.connect")

#: Close codes of the server's relay that mean "stop" rather than "reconnect".
REFUSED, FINISHED_CODE = 4003, 4010
#: Largest request frame accepted (an /act of 10,000 placed boxes is about 1.5 MB).
MAX_REQUEST_BYTES = 4 * 1024 * 1024
BACKOFF_S = (0.2, 0.5, 1.0, 2.0, 5.0)
_ECHO = b"{}"
_JSON = [("content-type", "application/json")]


class AppCaller:
    """Calls an ASGI app in-process for one request (its own event loop: one caller per thread)."""

    def __init__(self, app: Any) -> None:
        self.app = app
        self.loop = asyncio.new_event_loop()

    def __call__(
        self, method: str, path: str, headers: list[tuple[str, str]], body: bytes
    ) -> tuple[int, list[tuple[str, str]], bytes]:
        return self.loop.run_until_complete(self._call(method, path, headers, body))

    async def _call(
        self, method: str, path: str, headers: list[tuple[str, str]], body: bytes
    ) -> tuple[int, list[tuple[str, str]], bytes]:
        scope = {
            "type": "http",
            "asgi": {"version": "3.0"},
            "http_version": "1.1",
            "method": method,
            "scheme": "http",
            "path": path,
            "raw_path": path.encode(),
            "query_string": b"",
            "root_path": "",
            "headers": [(k.lower().encode("latin-1"), v.encode("latin-1")) for k, v in headers],
            "client": ("pull", 0),
            "server": ("pull", 0),
        }
        sent = False
        status, out_headers, chunks = 500, [], []

        async def receive() -> dict[str, Any]:
            nonlocal sent
            if sent:
                await asyncio.sleep(3600)  # no disconnect while the app runs
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}

        async def send(message: dict[str, Any]) -> None:
            nonlocal status, out_headers
            if message["type"] == "http.response.start":
                status = message["status"]
                out_headers = [
                    (k.decode("latin-1"), v.decode("latin-1")) for k, v in message.get("headers", [])
                ]
            elif message["type"] == "http.response.body":
                chunks.append(message.get("body", b""))

        await self.app(scope, receive, send)
        return status, out_headers, b"".join(chunks)

    def close(self) -> None:
        self.loop.close()


def relay_url(server: str, submission_id: int) -> str:
    parts = urlsplit(server.rstrip("/"))
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(f"the server URL must be http(s)://host[:port], got {server!r}")
    scheme = "wss" if parts.scheme == "https" else "ws"
    return f"{scheme}://{parts.netloc}{parts.path}/api/v1/pull/connect?submission={int(submission_id)}"


class _Stop(Exception):
    """The server said stop (finished submission, refused token): do not reconnect."""


def serve_connection(
    url: str,
    token: str,
    call: Callable[[str, str, list[tuple[str, str]], bytes], tuple[int, list[tuple[str, str]], bytes]],
    stop: threading.Event,
    *,
    on_event: Callable[[str], None] = lambda _m: None,
    ssl_context: Any = None,
) -> str:
    """Keep one connection to the relay open (reconnecting after drops) and answer its requests until
    ``stop`` is set or the server says stop. Returns why it stopped."""
    failures = 0
    while not stop.is_set():
        try:
            ws = ws_connect(
                url,
                additional_headers={"Authorization": f"Bearer {token}"},
                open_timeout=10,
                max_size=MAX_REQUEST_BYTES,
                compression=None,
                ping_interval=20,
                ping_timeout=20,
                user_agent_header=f"robobpp/{__version__}",
                **({"ssl": ssl_context} if ssl_context is not None else {}),
            )
        except (OSError, TimeoutError, InvalidHandshake, InvalidURI) as exc:
            delay = BACKOFF_S[min(failures, len(BACKOFF_S) - 1)]
            failures += 1
            on_event(f"cannot connect ({exc}); retrying in {delay:g} s")
            stop.wait(delay)
            continue
        with contextlib.suppress(OSError):
            ws.socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            with ws:
                _answer(ws, call, stop, on_event)
                failures = 0
        except _Stop as exc:
            return str(exc)
        except ConnectionClosed as exc:
            code, reason = (exc.rcvd.code, exc.rcvd.reason) if exc.rcvd else (None, "")
            if code in (REFUSED, FINISHED_CODE):
                on_event(f"the server ended the connection: {reason}")
                return reason
            delay = BACKOFF_S[min(failures, len(BACKOFF_S) - 1)]
            failures += 1
            on_event(f"connection lost ({code or 'no close frame'}); reconnecting in {delay:g} s")
            stop.wait(delay)
    return "stopped"


def _answer(
    ws: Any,
    call: Callable[..., tuple[int, list[tuple[str, str]], bytes]],
    stop: threading.Event,
    on_event: Callable[[str], None],
) -> None:
    welcome = ws.recv(timeout=15)
    hello = json.loads(welcome) if isinstance(welcome, str) else {}
    on_event(f"connected to submission {hello.get('submission', '?')}; waiting for episodes")
    while not stop.is_set():
        try:
            data = ws.recv(timeout=0.5)
        except TimeoutError:
            continue
        if isinstance(data, str):
            continue
        try:
            request = frames.decode(data)
        except ValueError as exc:
            on_event(f"ignored a malformed frame from the server: {exc}")
            continue
        path = "/" + str(request.envelope.get("path", "")).rsplit("/", 1)[-1]
        if path == "/echo":  # the evaluator's network probe: answer at once, the policy is not involved
            status, headers, body = 200, _JSON, _ECHO
        else:
            status, headers, body = call(
                str(request.envelope.get("method", "POST")), path, request.headers, request.body
            )
        ws.send(frames.encode({"id": request.id, "status": status}, headers, body))


def connect(
    policy: Any,
    server: str,
    token: str,
    *,
    submission: int | None = None,
    secret: str | None = None,
    name: str | None = None,
    datasets: list[str] | None = None,
    settings: list[str] | None = None,
    track: BoardTrack = "private",
    lookahead: int = 0,
    parallel: int = 1,
    on_event: Callable[[str], None] | None = None,
    stop: threading.Event | None = None,
    poll_s: float = 2.0,
    on_progress: Callable[[SubmissionPublic], None] | None = None,
) -> SubmissionPublic:
    """Evaluate ``policy`` on ``server`` in pull mode and return the finished submission.

    Without ``submission`` a new pull submission is created (``name``, ``datasets``, ``settings``,
    ``track``, ``lookahead`` as for ``robobpp submit``); with it, the client (re)joins that one, e.g.
    after a restart. ``policy`` is an object with ``act`` (shared by every connection, under a lock), or
    a class or other factory called once per connection. ``on_progress`` gets the submission each time it
    is polled (every ``poll_s`` seconds), as ``ServerClient.wait`` gives it.
    """
    from robobpp.client.serve import create_policy_app

    if parallel < 1:
        raise ValueError(f"parallel must be at least 1, got {parallel}")
    say = on_event or (lambda message: log.info("%s", message))
    stop = stop or threading.Event()
    factory = None if callable(getattr(policy, "act", None)) else policy
    if factory is not None and not callable(factory):
        raise TypeError(f"{type(policy).__name__} has no act(observation) method and is not a factory")
    shared = None if factory is not None else create_policy_app(policy, secret, name=name)
    lock = threading.Lock()
    with ServerClient(server, token) as api:
        if submission is None:
            sample = factory() if factory is not None else policy
            shown = name or getattr(sample, "name", None) or type(sample).__name__
            sub = api.submit(
                None,
                secret=secret,
                name=str(shown)[:64],
                datasets=datasets,
                settings=settings,
                track=track,
                lookahead=lookahead,
                mode="pull",
            )
            say(f"submitted #{sub.id} {sub.name} in pull mode: {sub.progress.episodes_total} episodes")
        else:
            sub = api.submission(submission)
        url = relay_url(server, sub.id)

        def run(index: int) -> None:
            if shared is not None:
                app = shared
            else:
                assert factory is not None  # no shared app: the policy is a factory
                app = create_policy_app(factory(), secret, name=name)
            caller = AppCaller(app)

            def call(*args: Any) -> tuple[int, list[tuple[str, str]], bytes]:
                if shared is None:
                    return caller(*args)
                with lock:  # one shared policy: it sees one request at a time, as with `serve`
                    return caller(*args)

            try:
                serve_connection(url, token, call, stop, on_event=lambda m: say(f"[{index}] {m}"))
            finally:
                caller.close()

        threads = [
            threading.Thread(target=run, args=(i,), name=f"robobpp-pull-{i}", daemon=True)
            for i in range(parallel)
        ]
        for thread in threads:
            thread.start()
        try:
            while not stop.is_set():
                try:
                    sub = api.submission(sub.id)
                except ServerError as exc:
                    if exc.status is not None:
                        raise
                    say(f"the server is not answering ({exc}); still trying")
                else:
                    if on_progress is not None:
                        on_progress(sub)
                if sub.status in FINISHED:
                    break
                if not any(t.is_alive() for t in threads):
                    break  # every connection was refused for good
                stop.wait(poll_s)
        finally:
            stop.set()
            deadline = time.monotonic() + 5
            for thread in threads:
                thread.join(timeout=max(0.0, deadline - time.monotonic()))
    return sub
