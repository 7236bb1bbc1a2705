"""Where the pull relay's two sockets meet: a message bus between the API processes of one deployment.

A pull episode joins two WebSockets (:mod:`robobpp.server.api.pull`): the participant's client connection and
the worker's episode socket. With several API processes (``robobpp serve --server-workers N``, or replicas on
several hosts behind one address) the two may land on different processes, so neither holds the other's
socket. Each socket's handler therefore owns an :class:`Endpoint` with an address, and the two talk only in
:class:`Message` s sent to each other's address. The bus delivers them and keeps each submission's queue of
idle client connections (their addresses):

- :class:`LocalBus`: the embedded default, one API process, no broker: delivery is a put into the
  endpoint's queue.
- :class:`RedisBus`: any number of processes and hosts through Redis (the deployment's Celery broker, or
  ``ROBOBPP_PULL_BROKER_URL``); :class:`robobpp.server.relay_amqp.AmqpBus` does the same through RabbitMQ. Each process subscribes to one channel of its own; a message to an endpoint
  of another process is one ``PUBLISH`` on that process's channel, a message between two endpoints of the
  same process never leaves it. The idle queues are Redis lists (``RPUSH``, ``BLPOP``).

Both buses answer a message sent to an address that no longer exists with :data:`GONE` from that address,
whatever the reason: the endpoint closed, its process exited or was killed (Redis then counts no subscriber
on the process's channel: ``PUBLISH`` returns 0), so a peer is never left waiting for a dead socket. A process
that dies while its peer is silent is noticed by :meth:`LocalBus.alive`, which the relay asks every
:data:`WATCH_S` seconds of silence.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import uuid
from collections import defaultdict, deque
from dataclasses import dataclass
from typing import Any

log = logging.getLogger("robobpp.server.pull")

#: Message kinds. The worker's side asks an idle client connection to ``PAIR``; it answers ``PAIRED`` (or
#: ``GONE`` when it is taken already); ``FRAME`` carries a frame either way; the client's side sends
#: ``TOO_LARGE`` instead of an answer over the cap; the worker's side ``RELEASE`` s the client connection when
#: its episode socket ends; ``GONE``: the sender's socket is gone (or the address never existed).
PAIR, PAIRED, FRAME, TOO_LARGE, RELEASE, GONE = "P", "A", "F", "L", "R", "G"
KINDS = frozenset({PAIR, PAIRED, FRAME, TOO_LARGE, RELEASE, GONE})
#: Seconds of silence after which a paired side checks that its peer's process is still there.
WATCH_S = 2.0
#: An idle submission queue left behind (every process of a deployment gone) expires after a day.
IDLE_QUEUE_TTL_S = 86_400
#: Redis connections of one API process for the client connections' commands (offer, withdraw, the idle
#: checks, liveness): a pool that makes a command wait for a free connection, never fail for want of one.
#: Each participant's connections hold at most :data:`PARTICIPANT_BUS_CALLS` of it at once (PullHub in
#: server/api/pull.py), so one participant's burst cannot take it from the others (docs/deploy.md,
#: "Several API processes").
POOL_CONNECTIONS = 100
#: How long a command waits for a free pooled connection before it fails (the caller retries or refuses).
POOL_WAIT_S = 10.0
#: Bus calls one participant's client connections have in flight at once in one API process.
PARTICIPANT_BUS_CALLS = 8
#: Redis connections for the workers' sides' ``BLPOP`` (each holds one while it waits for a client): their
#: number follows the episodes running, which the deployment's workers bound, not the participants.
TAKE_CONNECTIONS = 1000


@dataclass(frozen=True, slots=True)
class Message:
    kind: str
    sender: str
    payload: bytes = b""


class Endpoint:
    """One socket's handler as seen by the bus: an address and the queue of messages sent to it."""

    def __init__(self, bus: LocalBus, address: str) -> None:
        self.bus = bus
        self.address = address
        self.inbox: asyncio.Queue[Message] = asyncio.Queue()

    async def send(self, to: str, kind: str, payload: bytes = b"") -> None:
        await self.bus.send(to, Message(kind, self.address, payload))

    async def receive(self, timeout_s: float) -> Message | None:
        """The next message, or ``None`` after ``timeout_s`` of silence."""
        try:
            return await asyncio.wait_for(self.inbox.get(), timeout_s)
        except TimeoutError:
            return None

    def close(self) -> None:
        self.bus.forget(self.address)


class LocalBus:
    """Endpoints and idle queues of this process: the whole bus when the API runs as one process."""

    def __init__(self) -> None:
        self.node = "local"
        self._endpoints: dict[str, Endpoint] = {}
        self._numbers = itertools.count(1)
        self._idle: defaultdict[int, deque[str]] = defaultdict(deque)
        self._waiting: defaultdict[int, deque[asyncio.Future[str]]] = defaultdict(deque)

    async def start(self) -> None:
        """Ready to deliver (the in-process bus always is)."""

    async def close(self) -> None:
        """Stop delivering (nothing to release in-process)."""

    def endpoint(self) -> Endpoint:
        endpoint = Endpoint(self, f"{self.node}.{next(self._numbers)}")
        self._endpoints[endpoint.address] = endpoint
        return endpoint

    def forget(self, address: str) -> None:
        self._endpoints.pop(address, None)

    def is_here(self, address: str) -> bool:
        return address.split(".", 1)[0] == self.node

    async def send(self, to: str, message: Message) -> None:
        await self._deliver_here(to, message)

    async def _deliver_here(self, to: str, message: Message) -> None:
        endpoint = self._endpoints.get(to)
        if endpoint is not None:
            endpoint.inbox.put_nowait(message)
        elif message.kind != GONE:  # tell the sender at once, instead of letting it wait for an answer
            await self.send(message.sender, Message(GONE, to))

    async def alive(self, address: str) -> bool:
        return address in self._endpoints

    async def offer(self, submission_id: int, address: str) -> None:
        """``address`` is an idle client connection of the submission: hand it to a waiting worker, or queue it."""
        waiting = self._waiting[submission_id]
        while waiting:
            future = waiting.popleft()
            if not future.done():
                future.set_result(address)
                return
        self._waiting.pop(submission_id, None)
        self._idle[submission_id].append(address)

    async def still_offered(self, submission_id: int, address: str) -> None:
        """Queue ``address`` again if it is not queued (an idle entry taken by a worker that then vanished)."""
        if address not in self._idle.get(submission_id, ()):
            await self.offer(submission_id, address)

    async def withdraw(self, submission_id: int, address: str) -> None:
        idle = self._idle.get(submission_id)
        if idle is not None:
            with contextlib.suppress(ValueError):
                idle.remove(address)
            if not idle:
                del self._idle[submission_id]

    async def take(self, submission_id: int, timeout_s: float) -> str | None:
        """The address of an idle client connection of the submission, waiting up to ``timeout_s`` for one."""
        idle = self._idle.get(submission_id)
        if idle:
            address = idle.popleft()
            if not idle:
                del self._idle[submission_id]
            return address
        future: asyncio.Future[str] = asyncio.get_running_loop().create_future()
        self._waiting[submission_id].append(future)
        try:
            return await asyncio.wait_for(future, timeout_s)
        except TimeoutError:
            waiting = self._waiting.get(submission_id)
            if waiting is not None:
                with contextlib.suppress(ValueError):
                    waiting.remove(future)
                if not waiting:
                    del self._waiting[submission_id]
            return None


class RedisBus(LocalBus):
    """The bus through Redis: processes of one deployment (same database) meet under one key prefix."""

    def __init__(self, url: str, deployment: str) -> None:
        super().__init__()
        import redis.asyncio

        from robobpp.server.redis_wire import Address, Publisher

        self.node = uuid.uuid4().hex[:16]
        self.prefix = f"robobpp:pull:{deployment}"
        self._address = Address.parse(url)
        # Idle queues and liveness, once per pairing: a blocking pool (a burst waits, it does not fail).
        self._redis: Any = redis.asyncio.Redis(
            connection_pool=redis.asyncio.BlockingConnectionPool.from_url(
                url, max_connections=POOL_CONNECTIONS, timeout=POOL_WAIT_S
            )
        )
        # The workers' sides' BLPOPs hold a connection each while they wait: a pool of their own, so that
        # waiting workers and the client connections' commands never wait for each other.
        self._takes: Any = redis.asyncio.from_url(url, max_connections=TAKE_CONNECTIONS)
        self._publisher = Publisher(self._address)  # frames: every step (server/redis_wire.py)
        self._listener: asyncio.Task[None] | None = None

    def _channel(self, node: str) -> str:
        return f"{self.prefix}:node:{node}"

    def _queue(self, submission_id: int) -> str:
        return f"{self.prefix}:idle:{int(submission_id)}"

    async def start(self) -> None:
        from robobpp.server.redis_wire import Subscriber

        subscriber = Subscriber(self._address, self._channel(self.node).encode())
        await subscriber.subscribe()  # subscribed before any address of this node is handed out
        self._listener = asyncio.create_task(self._listen(subscriber), name="robobpp-pull-bus")

    async def close(self) -> None:
        if self._listener is not None:
            self._listener.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._listener
        await self._publisher.close()
        for client in (self._redis, self._takes):
            with contextlib.suppress(Exception):
                await client.aclose(close_connection_pool=True)

    async def _listen(self, subscriber: Any) -> None:
        try:
            while True:
                try:
                    data = await subscriber.message()
                except (OSError, EOFError) as exc:  # Redis restarted or the network blinked
                    log.warning("pull relay: lost the Redis subscription (%s); subscribing again", exc)
                    await self._resubscribe(subscriber)
                    continue
                decoded = decode(data)
                if decoded is None:
                    log.warning("pull relay: ignored a malformed bus message")
                    continue
                await self._deliver_here(*decoded)
        finally:
            subscriber.close()

    @staticmethod
    async def _resubscribe(subscriber: Any) -> None:
        while True:
            try:
                await subscriber.subscribe()
                return
            except (OSError, EOFError):
                await asyncio.sleep(0.5)

    async def send(self, to: str, message: Message) -> None:
        if self.is_here(to):
            await self._deliver_here(to, message)
            return
        channel = self._channel(to.split(".", 1)[0]).encode()
        try:
            delivered = await self._publisher.publish(channel, encode(to, message))
        except (OSError, EOFError) as exc:  # Redis is away: for the sender, its peer is gone
            log.warning("pull relay: cannot publish to Redis: %s", exc)
            delivered = asyncio.get_running_loop().create_future()
            delivered.set_exception(exc)
        # Not awaited: a frame's latency is one trip through Redis. Its answer comes back in order; when
        # no process was subscribed there (it exited or was killed) or the publish failed, the sender hears
        # GONE from the address, as from an endpoint that closed.
        delivered.add_done_callback(lambda done: self._published(done, to, message))

    def _published(self, done: asyncio.Future[int], to: str, message: Message) -> None:
        failed = done.cancelled() or done.exception() is not None
        if message.kind != GONE and (failed or done.result() == 0):
            asyncio.ensure_future(self._deliver_here(message.sender, Message(GONE, to)))

    async def alive(self, address: str) -> bool:
        if self.is_here(address):
            return await super().alive(address)
        ((_, subscribers),) = await self._redis.pubsub_numsub(self._channel(address.split(".", 1)[0]))
        return int(subscribers) > 0

    async def offer(self, submission_id: int, address: str) -> None:
        queue = self._queue(submission_id)
        async with self._redis.pipeline(transaction=False) as pipe:
            pipe.rpush(queue, address)
            pipe.expire(queue, IDLE_QUEUE_TTL_S)
            await pipe.execute()

    async def still_offered(self, submission_id: int, address: str) -> None:
        if await self._redis.lpos(self._queue(submission_id), address) is None:
            await self.offer(submission_id, address)

    async def withdraw(self, submission_id: int, address: str) -> None:
        await self._redis.lrem(self._queue(submission_id), 0, address)

    async def take(self, submission_id: int, timeout_s: float) -> str | None:
        # BLPOP's timeout has a resolution of 1 ms; 0 would mean "forever"
        popped = await self._takes.blpop([self._queue(submission_id)], timeout=max(timeout_s, 0.001))
        return None if popped is None else popped[1].decode("ascii")


def encode(to: str, message: Message) -> bytes:
    """``kind`` ``to`` LF ``sender`` LF ``payload`` (addresses are ASCII without LF; the payload is raw)."""
    return b"%s%s\n%s\n" % (message.kind.encode(), to.encode("ascii"), message.sender.encode("ascii")) + (
        message.payload
    )


def decode(data: bytes) -> tuple[str, Message] | None:
    try:
        to, sender, payload = data[1:].split(b"\n", 2)
        kind = data[:1].decode("ascii")
        if kind not in KINDS:
            return None
        return to.decode("ascii"), Message(kind, sender.decode("ascii"), payload)
    except (ValueError, UnicodeDecodeError):
        return None
