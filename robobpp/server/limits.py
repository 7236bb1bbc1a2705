"""Request body cap and deadline, enforced before the body is parsed (a 10 MB upload never reaches pydantic,
a body dripped one byte a second never holds a handler)."""

from __future__ import annotations

import asyncio
import json
import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from robobpp.server.problems import PROBLEM_MEDIA_TYPE, TYPE_BASE


class BodySizeLimit:
    """Pure ASGI middleware: refuse bodies over ``max_bytes`` by header or by counting the stream (413), and
    bodies not complete ``timeout_s`` after the headers (408; the headers' deadline is the connection
    guard's, :mod:`robobpp.server.connections`)."""

    def __init__(self, app: ASGIApp, max_bytes: int, timeout_s: float = 30.0) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.timeout_s = timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = -1
                if declared < 0 or declared > self.max_bytes:
                    await self._refuse(scope, send)
                    return
        # The body is read here, whole, under its deadline and cap, then handed to the app: a handler that
        # read it itself would turn a deadline into its own "error parsing the body" (400). Bodies are small
        # (``max_bytes``, 64 KiB by default), so holding one costs nothing.
        deadline = time.monotonic() + self.timeout_s
        chunks: list[bytes] = []
        seen = 0
        first: Message | None = None
        try:
            while True:
                message = await asyncio.wait_for(receive(), max(0.0, deadline - time.monotonic()))
                if message["type"] != "http.request":
                    first = message  # the client left mid-body: the app hears it as the first message
                    break
                chunks.append(message.get("body", b""))
                seen += len(chunks[-1])
                if seen > self.max_bytes:
                    await self._refuse(scope, send)
                    return
                if not message.get("more_body", False):
                    break
        except TimeoutError:
            await self._refuse(
                scope,
                send,
                408,
                "body-timeout",
                "Request body too slow",
                f"a request body must arrive within {self.timeout_s:g} s of its headers",
            )
            return
        replay: list[Message] = [
            first or {"type": "http.request", "body": b"".join(chunks), "more_body": False}
        ]

        async def buffered_receive() -> Message:
            return replay.pop() if replay else await receive()

        await self.app(scope, buffered_receive, send)

    async def _refuse(
        self,
        scope: Scope,
        send: Send,
        status: int = 413,
        kind: str = "body-too-large",
        title: str = "Request body too large",
        detail: str | None = None,
    ) -> None:
        body = json.dumps(
            {
                "type": TYPE_BASE + kind,
                "title": title,
                "status": status,
                "detail": detail or f"request bodies are limited to {self.max_bytes} bytes",
                "instance": scope.get("path"),
            }
        ).encode()
        await send(
            {
                "type": "http.response.start",
                "status": status,
                "headers": [
                    (b"content-type", PROBLEM_MEDIA_TYPE.encode()),
                    (b"content-length", str(len(body)).encode()),
                    (b"connection", b"close"),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})
