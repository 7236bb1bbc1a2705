"""``PUBLISH`` and ``SUBSCRIBE`` spoken directly over one connection each: the pull relay's per-step path.

Every step of a pull episode between two API processes is two ``PUBLISH`` es and two deliveries. Through
redis-py's asyncio client one such step cost 1.2–1.4 ms of CPU in the API processes (its command pipeline,
connection pool and observability hooks run for every command), against about 20 µs for the same command
written to a socket (BENCHMARKS.md, "Pull relay through Redis"). These two classes speak just what the step
needs of the Redis protocol (RESP2): a publisher that writes commands back to back on one connection and
reads the replies in order (the sender does not wait for them: a step's latency is one trip to Redis and
one delivery, not two trips), and a subscriber that reads the messages of its channel. Everything else the
relay asks Redis (idle queues, liveness) goes through redis-py, once per pairing, not per step.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import socket
import ssl
from dataclasses import dataclass
from urllib.parse import unquote, urlsplit

#: Above this many bytes waiting in the socket's buffer, a publisher waits for it to drain.
HIGH_WATER_BYTES = 1 << 20


class RedisWireError(ConnectionError):
    """The connection broke, or Redis answered an error."""


@dataclass(frozen=True, slots=True)
class Address:
    host: str = "127.0.0.1"
    port: int = 6379
    path: str = ""  # unix socket
    tls: bool = False
    username: str = ""
    password: str = ""

    @classmethod
    def parse(cls, url: str) -> Address:
        parts = urlsplit(url)
        if parts.scheme not in ("redis", "rediss", "unix"):
            raise ValueError(f"not a Redis URL: {url!r}")
        return cls(
            host=parts.hostname or "127.0.0.1",
            port=parts.port or 6379,
            path=parts.path if parts.scheme == "unix" else "",
            tls=parts.scheme == "rediss",
            username=unquote(parts.username or ""),
            password=unquote(parts.password or ""),
        )

    async def open(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        if self.path:
            reader, writer = await asyncio.open_unix_connection(self.path)
        else:
            context = ssl.create_default_context() if self.tls else None
            reader, writer = await asyncio.open_connection(self.host, self.port, ssl=context)
            sock = writer.get_extra_info("socket")
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if self.password:
            auth = [b"AUTH", self.username.encode(), self.password.encode()] if self.username else None
            writer.write(command(*(auth or [b"AUTH", self.password.encode()])))
            reply = await reader.readuntil(b"\r\n")
            if not reply.startswith(b"+"):
                writer.close()
                raise RedisWireError(f"Redis refused the credentials: {reply[:80]!r}")
        return reader, writer


def command(*args: bytes) -> bytes:
    """A command as RESP2 bulk strings."""
    out = [b"*%d\r\n" % len(args)]
    for arg in args:
        out.append(b"$%d\r\n" % len(arg))
        out.append(arg)
        out.append(b"\r\n")
    return b"".join(out)


async def read_reply(reader: asyncio.StreamReader) -> object:
    """One RESP2 reply: int, bytes, None, list, or :class:`RedisWireError` for an error reply."""
    line = await reader.readuntil(b"\r\n")
    kind, rest = line[:1], line[1:-2]
    if kind == b":":
        return int(rest)
    if kind == b"+":
        return rest
    if kind == b"-":
        return RedisWireError(rest.decode(errors="replace"))
    if kind == b"$":
        n = int(rest)
        if n < 0:
            return None
        return (await reader.readexactly(n + 2))[:-2]
    if kind == b"*":
        n = int(rest)
        return None if n < 0 else [await read_reply(reader) for _ in range(n)]
    raise RedisWireError(f"unexpected reply from Redis: {line[:80]!r}")


class Publisher:
    """``PUBLISH`` on one connection: commands written back to back, replies matched in order."""

    def __init__(self, address: Address) -> None:
        self.address = address
        self._writer: asyncio.StreamWriter | None = None
        self._pending: collections.deque[asyncio.Future[int]] = collections.deque()
        self._reading: asyncio.Task[None] | None = None
        self._opening = asyncio.Lock()

    async def _connect(self) -> asyncio.StreamWriter:
        async with self._opening:
            if self._writer is None or self._writer.is_closing():
                reader, self._writer = await self.address.open()
                self._reading = asyncio.create_task(self._replies(reader), name="robobpp-redis-replies")
            return self._writer

    async def _replies(self, reader: asyncio.StreamReader) -> None:
        try:
            while True:
                reply = await read_reply(reader)
                future = self._pending.popleft()
                if future.done():
                    continue
                if isinstance(reply, int):
                    future.set_result(reply)
                else:
                    future.set_exception(RedisWireError(f"PUBLISH answered {reply!r}"))
        except (OSError, EOFError, asyncio.IncompleteReadError, IndexError, RedisWireError) as exc:
            self._fail(exc)

    def _fail(self, exc: BaseException) -> None:
        if self._writer is not None:
            self._writer.close()
        while self._pending:
            future = self._pending.popleft()
            if not future.done():
                future.set_exception(RedisWireError(f"the connection to Redis broke: {exc}"))

    async def publish(self, channel: bytes, data: bytes) -> asyncio.Future[int]:
        """Send ``PUBLISH`` and return at once (it waits only while the socket's buffer is full); the
        future resolves to how many subscribers received ``data`` (0: none is listening on ``channel``).
        Messages published from one process reach a subscriber in the order they were published."""
        writer = self._writer
        if writer is None or writer.is_closing():
            writer = await self._connect()
        future: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        self._pending.append(future)
        writer.write(command(b"PUBLISH", channel, data))
        if writer.transport.get_write_buffer_size() > HIGH_WATER_BYTES:
            await writer.drain()
        return future

    async def close(self) -> None:
        if self._reading is not None:
            self._reading.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._reading
        self._fail(RedisWireError("closed"))


class Subscriber:
    """The messages published on one channel, read from a connection of their own."""

    def __init__(self, address: Address, channel: bytes) -> None:
        self.address, self.channel = address, channel
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None

    async def subscribe(self) -> None:
        """Connect and subscribe; returns once Redis confirmed the subscription."""
        self.close()
        reader, writer = await self.address.open()
        writer.write(command(b"SUBSCRIBE", self.channel))
        reply = await read_reply(reader)
        if not (isinstance(reply, list) and reply[:1] == [b"subscribe"]):
            writer.close()
            raise RedisWireError(f"SUBSCRIBE answered {reply!r}")
        self._reader, self._writer = reader, writer

    async def message(self) -> bytes:
        """The next message's data (raises :class:`RedisWireError` or ``OSError`` when the connection broke)."""
        if self._reader is None:
            raise RedisWireError("not subscribed")
        while True:
            try:
                reply = await read_reply(self._reader)
            except asyncio.IncompleteReadError as exc:
                raise RedisWireError("the connection to Redis closed") from exc
            if isinstance(reply, list) and len(reply) == 3 and reply[0] == b"message":
                data = reply[2]
                if isinstance(data, bytes):
                    return data

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
        self._reader = self._writer = None
