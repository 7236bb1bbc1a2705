"""The pull relay's bus through RabbitMQ, for deployments whose Celery broker is RabbitMQ (``amqp://``).

The same bus as :class:`robobpp.server.relay_bus.RedisBus`, with AMQP's parts:

- each API process declares an *exclusive* queue of its own (RabbitMQ deletes it with the process's
  connection) and consumes it; a message to an endpoint of another process is published to that queue through
  the default exchange with ``mandatory``, so a message to a process that is gone comes back (``basic.return``)
  and its sender hears :data:`~robobpp.server.relay_bus.GONE`, as with Redis's ``PUBLISH`` reaching no one;
- a peer's liveness is a passive ``queue.declare`` of its process's queue (``RESOURCE_LOCKED``: it exists,
  exclusive to a live connection; ``NOT_FOUND``: it went with its process);
- the idle client connections of a submission wait in a queue of the submission (``x-expires``: a day unused),
  taken with ``basic.get``. AMQP cannot remove a message from the middle of a queue, so an idle connection that
  leaves stays there until a worker takes it: its ``PAIR`` is answered ``GONE`` (by its process, or by
  ``basic.return`` when its process is gone) and the worker takes the next one.

py-amqp is synchronous: a consumer thread reads the process's queue and hands each message to the event loop;
one broker thread does everything else in order (publishes, declares, gets), so the frames of a step leave in
the order they were sent.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import queue
import socket
import threading
import uuid
from collections.abc import Callable
from typing import Any
from urllib.parse import unquote, urlsplit

from robobpp.server.relay_bus import GONE, IDLE_QUEUE_TTL_S, LocalBus, Message, decode, encode

log = logging.getLogger("robobpp.server.pull")

#: How often a worker's side asks the submission's idle queue again while it waits for a client.
TAKE_POLL_S = 0.05


def connection_options(url: str) -> dict[str, Any]:
    """py-amqp's connection arguments from a Celery-style ``amqp://user:password@host:port/vhost`` URL."""
    parts = urlsplit(url)
    if parts.scheme not in ("amqp", "amqps", "pyamqp"):
        raise ValueError(f"not an AMQP URL: {url!r}")
    vhost = parts.path[1:] if parts.path.startswith("/") else parts.path
    return {
        "host": f"{parts.hostname or '127.0.0.1'}:{parts.port or 5672}",
        "userid": unquote(parts.username or "guest"),
        "password": unquote(parts.password or "guest"),
        "virtual_host": unquote(vhost) or "/",
        "ssl": parts.scheme == "amqps",
        "connect_timeout": 10,
    }


class AmqpBus(LocalBus):
    """The bus through RabbitMQ: processes of one deployment (same database) meet under one name prefix."""

    def __init__(self, url: str, deployment: str) -> None:
        super().__init__()
        self.node = uuid.uuid4().hex[:16]
        self.prefix = f"robobpp.pull.{deployment}"
        self._options = connection_options(url)
        self._jobs: queue.SimpleQueue[tuple[Callable[[Any], Any], concurrent.futures.Future[Any]] | None] = (
            queue.SimpleQueue()
        )
        self._closing = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._threads: list[threading.Thread] = []

    def _node_queue(self, node: str) -> str:
        return f"{self.prefix}.node.{node}"

    def _idle_queue(self, submission_id: int) -> str:
        return f"{self.prefix}.idle.{int(submission_id)}"

    def _connect(self) -> Any:
        import amqp

        connection = amqp.Connection(**self._options)
        connection.connect()
        return connection

    # --- threads -------------------------------------------------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        subscribed: concurrent.futures.Future[None] = concurrent.futures.Future()
        for target, args in ((self._consume, (subscribed,)), (self._work, ())):
            thread = threading.Thread(target=target, args=args, name="robobpp-pull-amqp", daemon=True)
            thread.start()
            self._threads.append(thread)
        await asyncio.wrap_future(
            subscribed
        )  # this node's queue exists before any address of it is handed out

    async def close(self) -> None:
        self._closing.set()
        self._jobs.put(None)
        for thread in self._threads:
            await asyncio.to_thread(thread.join, 5)

    def _consume(self, subscribed: concurrent.futures.Future[None]) -> None:
        while not self._closing.is_set():
            try:
                connection = self._connect()
                channel = connection.channel()
                channel.queue_declare(self._node_queue(self.node), exclusive=True, auto_delete=True)
                channel.basic_consume(self._node_queue(self.node), no_ack=True, callback=self._arrived)
            except Exception as exc:  # noqa: BLE001 - RabbitMQ is away: say so at start, retry later
                if not subscribed.done():
                    subscribed.set_exception(exc)
                    return
                log.warning("pull relay: cannot consume from RabbitMQ (%s); retrying", exc)
                self._closing.wait(0.5)
                continue
            if not subscribed.done():
                subscribed.set_result(None)
            try:
                while not self._closing.is_set():
                    with contextlib.suppress(socket.timeout, TimeoutError):
                        connection.drain_events(timeout=0.5)
            except Exception as exc:  # noqa: BLE001 - the connection broke: consume again
                log.warning("pull relay: lost the RabbitMQ consumer (%s); consuming again", exc)
            finally:
                with contextlib.suppress(Exception):
                    connection.close()

    def _arrived(self, amqp_message: Any) -> None:
        decoded = decode(bytes(amqp_message.body))
        if decoded is None:
            log.warning("pull relay: ignored a malformed bus message")
            return
        assert self._loop is not None
        self._loop.call_soon_threadsafe(lambda: asyncio.ensure_future(self._deliver_here(*decoded)))

    def _work(self) -> None:
        """The broker thread: runs jobs in order; between them reads what the broker sends back (returns)."""
        connection = channel = None
        while True:
            try:
                job = self._jobs.get(timeout=0.05)
            except queue.Empty:
                job = None
            if job is None and self._closing.is_set():
                break
            try:
                if connection is None:
                    connection = self._connect()
                    channel = connection.channel()
                    channel.events["basic_return"].add(self._returned)
                if job is None:
                    with contextlib.suppress(socket.timeout, TimeoutError):
                        connection.drain_events(timeout=0.001)
                    continue
            except Exception as exc:  # noqa: BLE001 - RabbitMQ is away: fail this job, connect again
                connection = channel = None
                if job is not None:
                    job[1].set_exception(exc)
                else:
                    self._closing.wait(0.2)
                continue
            fn, future = job
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn(channel))
            except Exception as exc:  # noqa: BLE001 - handed to the caller
                future.set_exception(exc)
                if getattr(channel, "is_open", False) is False:  # a channel error closed it (e.g. NotFound)
                    with contextlib.suppress(Exception):
                        channel = connection.channel()
                        channel.events["basic_return"].add(self._returned)
        if connection is not None:
            with contextlib.suppress(Exception):
                connection.close()

    def _returned(self, _exc: Any, _exchange: str, _routing_key: str, amqp_message: Any) -> None:
        """A message no queue took (its process is gone): its sender hears GONE from the address."""
        decoded = decode(bytes(amqp_message.body))
        if decoded is None or decoded[1].kind == GONE:
            return
        to, message = decoded
        assert self._loop is not None
        self._loop.call_soon_threadsafe(
            lambda: asyncio.ensure_future(self._deliver_here(message.sender, Message(GONE, to)))
        )

    def _submit(self, fn: Callable[[Any], Any]) -> concurrent.futures.Future[Any]:
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        self._jobs.put((fn, future))
        return future

    # --- the bus -------------------------------------------------------------------------------------------

    async def send(self, to: str, message: Message) -> None:
        if self.is_here(to):
            await self._deliver_here(to, message)
            return
        import amqp

        body, routing_key = encode(to, message), self._node_queue(to.split(".", 1)[0])
        future = self._submit(
            lambda channel: channel.basic_publish(
                amqp.Message(body), exchange="", routing_key=routing_key, mandatory=True
            )
        )
        # Not awaited (a frame's latency is one trip through the broker); a failed publish is GONE.
        future.add_done_callback(lambda done: self._published(done, to, message))

    def _published(self, done: concurrent.futures.Future[Any], to: str, message: Message) -> None:
        if message.kind != GONE and (done.cancelled() or done.exception() is not None):
            assert self._loop is not None
            self._loop.call_soon_threadsafe(
                lambda: asyncio.ensure_future(self._deliver_here(message.sender, Message(GONE, to)))
            )

    async def alive(self, address: str) -> bool:
        if self.is_here(address):
            return await super().alive(address)
        name = self._node_queue(address.split(".", 1)[0])
        import amqp

        try:
            await asyncio.wrap_future(self._submit(lambda channel: channel.queue_declare(name, passive=True)))
        except amqp.exceptions.NotFound:  # deleted with its process's connection
            return False
        except amqp.exceptions.ResourceLocked:  # exclusive to a live connection: the process is there
            return True
        return True

    def _declare_idle(self, channel: Any, submission_id: int) -> str:
        name = self._idle_queue(submission_id)
        channel.queue_declare(
            name, durable=False, auto_delete=False, arguments={"x-expires": IDLE_QUEUE_TTL_S * 1000}
        )
        return name

    async def offer(self, submission_id: int, address: str) -> None:
        import amqp

        def publish(channel: Any) -> None:
            name = self._declare_idle(channel, submission_id)
            channel.basic_publish(amqp.Message(address.encode("ascii")), exchange="", routing_key=name)

        await asyncio.wrap_future(self._submit(publish))

    async def still_offered(self, submission_id: int, address: str) -> None:
        """AMQP cannot look inside a queue; an entry taken by a worker that then vanished is put back by
        :meth:`take` itself when its caller is cancelled."""

    async def withdraw(self, submission_id: int, address: str) -> None:
        """Left in the queue (AMQP cannot remove it): the worker that takes it hears ``GONE`` and goes on."""

    async def take(self, submission_id: int, timeout_s: float) -> str | None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s

        def get(channel: Any) -> str | None:
            message = channel.basic_get(self._declare_idle(channel, submission_id), no_ack=True)
            return None if message is None else bytes(message.body).decode("ascii")

        while True:
            future = self._submit(get)
            try:
                address: str | None = await asyncio.shield(asyncio.wrap_future(future))
            except asyncio.CancelledError:  # taken from the queue for nobody: put it back once it arrives
                future.add_done_callback(lambda done: self._put_back(done, submission_id))
                raise
            if address is not None:
                return address
            if loop.time() >= deadline:
                return None
            await asyncio.sleep(min(TAKE_POLL_S, max(0.0, deadline - loop.time())))

    def _put_back(self, done: concurrent.futures.Future[Any], submission_id: int) -> None:
        if done.cancelled() or done.exception() is not None or done.result() is None:
            return
        address = done.result()
        import amqp

        self._submit(
            lambda channel: channel.basic_publish(
                amqp.Message(address.encode("ascii")),
                exchange="",
                routing_key=self._idle_queue(submission_id),
            )
        )
