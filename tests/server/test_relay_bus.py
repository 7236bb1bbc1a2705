"""The relay bus on its own: in-process, and between two Redis-backed buses (two API processes' worth) through
the real Redis. A frame arrives in order, an address that is gone answers GONE (a closed endpoint, or a whole
process whose subscription ended), idle queues hand out each client connection once, and garbage published on
a process's channel is ignored."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
import time
import uuid
from collections.abc import Awaitable, Callable, Iterator
from pathlib import Path

import pytest
import redis

from robobpp.server.relay_amqp import AmqpBus
from robobpp.server.relay_bus import FRAME, GONE, PAIR, Endpoint, LocalBus, Message, RedisBus, decode, encode
from tests._orphans import with_parent_death
from tests.server.conftest import AMQP_URL, REDIS_URL, free_port, rabbitmq_or_skip, redis_or_skip

Pair = tuple[LocalBus, LocalBus]


def _buses(kind: str) -> Pair:
    if kind == "in-process":
        bus = LocalBus()
        return bus, bus
    deployment = f"test-{uuid.uuid4().hex[:12]}"
    if kind == "amqp":
        rabbitmq_or_skip()
        return AmqpBus(AMQP_URL, deployment), AmqpBus(AMQP_URL, deployment)
    redis_or_skip()
    return RedisBus(REDIS_URL, deployment), RedisBus(REDIS_URL, deployment)


def _run(kind: str, body: Callable[[Pair], Awaitable[None]]) -> None:
    async def main() -> None:
        buses = _buses(kind)
        for bus in {id(b): b for b in buses}.values():
            await bus.start()
        try:
            await body(buses)
        finally:
            for bus in {id(b): b for b in buses}.values():
                await bus.close()

    asyncio.run(main())


KINDS = [
    "in-process",
    pytest.param("redis", marks=pytest.mark.redis),
    pytest.param("amqp", marks=pytest.mark.rabbitmq),
]


async def _next(endpoint: Endpoint) -> Message:
    message = await endpoint.receive(5)
    assert message is not None, "nothing arrived within 5 s"
    return message


@pytest.mark.parametrize("kind", KINDS)
def test_frames_arrive_in_order_with_their_bytes_intact(kind: str) -> None:
    async def body(buses: Pair) -> None:
        worker, client = buses[0].endpoint(), buses[1].endpoint()
        payloads = [bytes([i % 256]) * (i * 37) + b"\n\r\n\x00" for i in range(60)]
        for payload in payloads:
            await worker.send(client.address, FRAME, payload)
        got = [await _next(client) for _ in payloads]
        assert [m.payload for m in got] == payloads
        assert {(m.kind, m.sender) for m in got} == {(FRAME, worker.address)}

    _run(kind, body)


@pytest.mark.parametrize("kind", KINDS)
def test_a_message_to_a_closed_endpoint_comes_back_as_gone(kind: str) -> None:
    async def body(buses: Pair) -> None:
        worker, client = buses[0].endpoint(), buses[1].endpoint()
        client.close()
        await worker.send(client.address, PAIR)
        answer = await _next(worker)
        assert (answer.kind, answer.sender) == (GONE, client.address)
        # in-process the endpoint is the unit; through a broker the process is, and the client's is still up
        assert await buses[0].alive(client.address) is (kind != "in-process")

    _run(kind, body)


@pytest.mark.parametrize("kind", KINDS)
def test_each_idle_connection_is_handed_out_once_in_order(kind: str) -> None:
    async def body(buses: Pair) -> None:
        submission = 7
        assert await buses[1].take(submission, 0.2) is None  # nobody connected: the wait ends empty
        await buses[0].offer(submission, "a.1")
        await buses[0].offer(submission, "a.2")
        if (
            kind != "amqp"
        ):  # AMQP cannot take a message out of a queue's middle: "a.1" would be taken, PAIR → GONE
            await buses[0].withdraw(submission, "a.1")  # that client left before a worker came
            assert await buses[1].take(submission, 1) == "a.2"
        else:
            assert [await buses[1].take(submission, 1) for _ in "12"] == ["a.1", "a.2"]
        waiting = asyncio.ensure_future(buses[1].take(submission, 5))
        await asyncio.sleep(0.2)
        await buses[0].offer(submission, "a.3")  # a worker already waiting gets it
        assert await waiting == "a.3"
        assert await buses[1].take(submission, 0.2) is None

    _run(kind, body)


@pytest.mark.parametrize(
    "kind", [pytest.param("redis", marks=pytest.mark.redis), pytest.param("amqp", marks=pytest.mark.rabbitmq)]
)
def test_an_address_of_a_process_that_went_away_is_gone_and_not_alive(kind: str) -> None:
    async def body(buses: Pair) -> None:
        worker, client = buses[0].endpoint(), buses[1].endpoint()
        assert await buses[0].alive(client.address)
        await buses[1].close()  # the client's API process exits: its channel has no subscriber left
        assert not await buses[0].alive(client.address)
        await worker.send(client.address, FRAME, b"anyone?")
        answer = await _next(worker)
        assert (answer.kind, answer.sender) == (GONE, client.address)

    _run(kind, body)


@pytest.mark.redis
def test_garbage_on_a_process_channel_is_ignored() -> None:
    async def body(buses: Pair) -> None:
        import redis.asyncio

        a, b = buses
        assert isinstance(b, RedisBus)
        worker, client = a.endpoint(), b.endpoint()
        raw = redis.asyncio.from_url(REDIS_URL)
        try:
            channel = f"{b.prefix}:node:{b.node}"
            for junk in (b"", b"Z" + b"x" * 50, b"Fno-newlines", b"F\xff\xfe\n\n"):
                await raw.publish(channel, junk)
        finally:
            await raw.aclose()
        await worker.send(client.address, FRAME, b"after the junk")
        message = await _next(client)
        assert (message.kind, message.payload) == (FRAME, b"after the junk")

    _run("redis", body)


def test_the_wire_format_round_trips_and_rejects_unknown_kinds() -> None:
    message = Message(FRAME, "n1.4", b"\n\x00body\n")
    assert decode(encode("n2.9", message)) == ("n2.9", message)
    assert decode(b"Qn2.9\nn1.4\nbody") is None
    assert decode(b"Fmissing-parts") is None


@pytest.mark.redis
def test_a_bus_cut_off_from_redis_answers_gone_then_works_again_when_redis_is_back() -> None:
    """Bus B reaches Redis through a TCP relay that the test cuts: while B is cut off, what A sends to B's
    endpoints and what B's endpoints send come back as GONE (no one waits on a dead path); once Redis is
    reachable again, B subscribes again and both directions work without a restart."""
    from tests.celery.relay import Relay

    redis_or_skip()
    relay = Relay(("127.0.0.1", int(REDIS_URL.rsplit(":", 1)[1].split("/")[0])))
    relay.up()

    async def main() -> None:
        deployment = f"test-{uuid.uuid4().hex[:12]}"
        a, b = RedisBus(REDIS_URL, deployment), RedisBus(f"redis://127.0.0.1:{relay.port}/0", deployment)
        await a.start()
        await b.start()
        try:
            worker, client = a.endpoint(), b.endpoint()
            await worker.send(client.address, FRAME, b"before")
            assert (await _next(client)).payload == b"before"
            relay.down()
            await asyncio.sleep(0.3)
            await worker.send(client.address, FRAME, b"while cut")
            assert (await _next(worker)).kind == GONE  # B's subscription is gone with its connection
            await client.send(worker.address, FRAME, b"while cut")
            assert (await _next(client)).kind == GONE  # B cannot publish
            relay.up()
            deadline = asyncio.get_running_loop().time() + 10
            while not await a.alive(client.address):  # B subscribed again
                assert asyncio.get_running_loop().time() < deadline, "B did not subscribe again"
                await asyncio.sleep(0.2)
            await worker.send(client.address, FRAME, b"after")
            assert (await _next(client)).payload == b"after"
            await client.send(worker.address, FRAME, b"back")
            assert (await _next(worker)).payload == b"back"
        finally:
            await a.close()
            await b.close()

    try:
        asyncio.run(main())
    finally:
        relay.close()


@pytest.fixture
def redis_with_password(tmp_path: Path) -> Iterator[tuple[int, str]]:
    """A private redis-server that requires a password, as the compose file's does (skips without the binary)."""
    binary = shutil.which("redis-server")
    if binary is None:
        pytest.skip("redis-server is not installed")
    port, password = free_port(), "s3cret-relay-pw"
    proc = subprocess.Popen(
        with_parent_death(
            [binary, "--port", str(port), "--bind", "127.0.0.1", "--requirepass", password, "--save", ""]
            + ["--appendonly", "no", "--dir", str(tmp_path)]
        ),
        stdout=subprocess.DEVNULL,
    )
    try:
        client = redis.Redis(port=port, password=password)
        for _ in range(50):
            try:
                client.ping()
                break
            except redis.ConnectionError:
                time.sleep(0.1)
        yield port, password
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.mark.redis
def test_the_bus_authenticates_with_the_url_s_password(redis_with_password: tuple[int, str]) -> None:
    """The compose file's broker URL carries a password (``redis://:PASSWORD@redis:6379/0``): the relay's own
    connections send it, and a wrong one fails the start with Redis's reason, not later and silently."""
    from robobpp.server.redis_wire import RedisWireError

    port, password = redis_with_password

    async def main() -> None:
        deployment = f"test-{uuid.uuid4().hex[:12]}"
        good = f"redis://:{password}@127.0.0.1:{port}/0"
        a, b = RedisBus(good, deployment), RedisBus(good, deployment)
        await a.start()
        await b.start()
        try:
            worker, client = a.endpoint(), b.endpoint()
            await worker.send(client.address, FRAME, b"authenticated")
            assert (await _next(client)).payload == b"authenticated"
            await client.send(worker.address, FRAME, b"both ways")
            assert (await _next(worker)).payload == b"both ways"
        finally:
            await a.close()
            await b.close()
        wrong = RedisBus(f"redis://:not-it@127.0.0.1:{port}/0", deployment)
        with pytest.raises(RedisWireError, match="refused the credentials"):
            await wrong.start()
        await wrong.close()

    asyncio.run(main())
