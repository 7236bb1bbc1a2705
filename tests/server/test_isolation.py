"""Isolation between participants (real server, real sockets): one participant's burst of pull connections
through the Redis relay leaves another participant's connections working.

Before: 150 pull sockets of one participant on a fresh server exhausted the relay's Redis connection pool
(redis-py's 100): 112 tracebacks in the server log, and all 4 connections of another participant dropped."""

from __future__ import annotations

import asyncio
import hashlib
import json
from pathlib import Path
from typing import Any

import httpx
import redis
from websockets.asyncio.client import connect as ws_connect
from websockets.exceptions import ConnectionClosed

from tests.server.conftest import ADMIN_TOKEN, REDIS_URL, new_participant, redis_or_skip


def _pull_submission(client: httpx.Client, name: str) -> int:
    made = client.post("/submissions", json={"name": name, "mode": "pull", "datasets": ["diverse"]})
    assert made.status_code == 201, made.text
    return int(made.json()["id"])


async def _open(base: str, token: str, submission: int) -> Any:
    """A client connection past its welcome, or the close code it was refused with."""
    url = base.replace("http", "ws") + f"/api/v1/pull/connect?submission={submission}"
    ws = await ws_connect(url, additional_headers={"Authorization": f"Bearer {token}"}, open_timeout=30)
    try:
        hello = json.loads(await asyncio.wait_for(ws.recv(), 30))
    except ConnectionClosed as exc:
        return exc.rcvd.code if exc.rcvd else None
    assert hello["type"] == "welcome"
    return ws


async def _alive(ws: Any) -> bool:
    try:
        await asyncio.wait_for(await ws.ping(), 10)
    except (ConnectionClosed, TimeoutError):
        return False
    return True


def test_a_burst_of_one_participant_s_pull_sockets_leaves_another_s_working(
    make_server, tmp_path: Path
) -> None:
    redis_or_skip()
    db = f"sqlite:///{tmp_path / 'burst.sqlite3'}"
    server = make_server(
        db,
        ROBOBPP_PULL_BROKER_URL=REDIS_URL,
        ROBOBPP_WORKERS="0",
        ROBOBPP_EVALUATE_BASELINES="0",
        ROBOBPP_QUOTA_CONCURRENT="5",
    )
    with server.client(ADMIN_TOKEN) as admin:
        flooder, other = new_participant(admin, "flooder"), new_participant(admin, "other")
    with server.client(flooder) as mine, server.client(other) as theirs:
        floods = [_pull_submission(mine, f"flood-{i}") for i in range(3)]
        kept = _pull_submission(theirs, "kept")
    queue = f"robobpp:pull:{hashlib.sha256(db.encode()).hexdigest()[:16]}:idle:{kept}"
    bus = redis.Redis.from_url(REDIS_URL)

    async def scenario() -> tuple[list[Any], list[bool], list[bool], int]:
        others = [await _open(server.url, other, kept) for _ in range(4)]
        assert not any(isinstance(ws, int) for ws in others)
        # 150 at once, 50 per submission: the participant's cap (128) admits 128, refuses 22 with 4029.
        burst = await asyncio.gather(
            *(_open(server.url, flooder, floods[i % 3]) for i in range(150)), return_exceptions=True
        )
        # Three rounds of the idle connections' checks (every 2 s), all 128 + 4 of them at once.
        await asyncio.sleep(7)
        others_alive = [await _alive(ws) for ws in others]
        burst_alive = [await _alive(ws) for ws in burst if not isinstance(ws, (int, BaseException))]
        queued = int(bus.llen(queue))  # the other's idle connections are still offered to the workers
        for ws in [*others, *burst]:
            if not isinstance(ws, (int, BaseException)):
                await ws.close()
        return burst, others_alive, burst_alive, queued

    burst, others_alive, burst_alive, queued = asyncio.run(scenario())
    refused = [b for b in burst if isinstance(b, int)]
    errors = [b for b in burst if isinstance(b, BaseException)]
    log = server.log.read_text()
    assert not errors, errors[:3]
    assert others_alive == [True] * 4 and queued == 4  # the other participant's connections survive the burst
    assert refused == [4029] * 22 and burst_alive == [True] * 128  # the excess gets a clear refusal
    assert "Traceback" not in log and "Too many connections" not in log, log[-3000:]


# Rate limits behind a proxy. Before: with uvicorn trusting every peer (``FORWARDED_ALLOW_IPS="*"``, which the
# deployment guide recommended), a client rotating ``X-Forwarded-For`` got 60 wrong API tokens and 30 wrong
# sign-ins answered 401, never 429.

LIMIT = 5


def _limited_server(tmp: Path, **settings: Any) -> Any:
    from tests.server.test_limits import _server

    return _server(tmp, auth_failures_per_minute=LIMIT, **settings).start()


def _from(server: Any, peer: str) -> httpx.Client:
    """A client whose connections come from ``peer`` (a loopback address other than 127.0.0.1 is no proxy)."""
    return httpx.Client(base_url=server.url, transport=httpx.HTTPTransport(local_address=peer), timeout=10)


def _me(client: httpx.Client, token: str, forwarded: str) -> int:
    headers = {"Authorization": f"Bearer {token}", "X-Forwarded-For": forwarded}
    return client.get("/api/v1/me", headers=headers).status_code


def _sign_in(client: httpx.Client, token: str, forwarded: str) -> int:
    import re

    page = client.get("/sign-in", headers={"X-Forwarded-For": forwarded}).text
    csrf = re.search(r'name="csrf" value="([^"]+)"', page)
    assert csrf is not None
    headers = {"X-Forwarded-For": forwarded, "Origin": str(client.base_url).rstrip("/")}
    r = client.post("/sign-in", data={"token": token, "csrf": csrf.group(1)}, headers=headers)
    return r.status_code


def _participants(server: Any, *names: str) -> list[str]:
    from tests.server.test_limits import ADMIN

    with httpx.Client(base_url=server.url + "/api/v1", headers={"Authorization": f"Bearer {ADMIN}"}) as admin:
        return [admin.post("/participants", json={"name": n}).json()["token"] for n in names]


def test_rotating_forwarded_for_from_a_peer_that_is_no_proxy_is_limited(tmp_path: Path) -> None:
    server = _limited_server(tmp_path)  # trusted proxies: 127.0.0.1 only (the default)
    try:
        with _from(server, "127.0.0.2") as api:
            codes = [_me(api, f"rbp_{i:06d}wrong", f"198.51.100.{i}") for i in range(LIMIT + 3)]
        assert codes == [401] * LIMIT + [429] * 3, codes
        with _from(server, "127.0.0.3") as browser:
            codes = [_sign_in(browser, f"rbp_{i:06d}nope", f"198.51.100.{i}") for i in range(LIMIT + 3)]
        assert codes == [401] * LIMIT + [429] * 3, codes
    finally:
        server.stop()


def test_behind_a_trusted_proxy_the_client_s_own_address_counts(tmp_path: Path) -> None:
    """The proxy (127.0.0.1, trusted) appends the address it saw to whatever the client sent: the rightmost
    address that is not a trusted proxy is the client's, however the client rotates the rest."""
    server = _limited_server(tmp_path)
    try:
        (token,) = _participants(server, "bystander")
        with _from(server, "127.0.0.1") as proxy:
            codes = [_me(proxy, f"rbp_{i:06d}wrong", f"10.0.0.{i}, 203.0.113.9") for i in range(LIMIT + 2)]
            assert codes == [401] * LIMIT + [429] * 2, codes
            assert _me(proxy, token, "203.0.113.10") == 200  # another client behind the same proxy
    finally:
        server.stop()


def test_wrong_tokens_are_limited_per_prefix_and_per_participant_whatever_the_address(tmp_path: Path) -> None:
    from tests.server.test_limits import ADMIN

    server = _limited_server(tmp_path)
    try:
        with httpx.Client(
            base_url=server.url + "/api/v1", headers={"Authorization": f"Bearer {ADMIN}"}
        ) as admin:
            made = admin.post("/participants", json={"name": "alice"}).json()
            first, pid = made["token"], made["participant"]["id"]
            second = admin.post(f"/participants/{pid}/tokens").json()["token"]
            bob = admin.post("/participants", json={"name": "bob"}).json()["token"]
        with _from(server, "127.0.0.1") as proxy:  # the trusted proxy, passing on a new client each time
            # One prefix, whatever the address: nobody's (rbp_zzzzzz), refused after the limit.
            codes = [_me(proxy, f"rbp_zzzzzz{i:04d}", f"203.0.113.{i}") for i in range(LIMIT + 1)]
            assert codes == [401] * LIMIT + [429], codes
            # One participant, whatever the prefix: 3 guesses at alice's first token, 2 at her second...
            guesses = [first[:10] + f"a{i}" for i in range(3)] + [second[:10] + f"b{i}" for i in range(2)]
            codes = [_me(proxy, g, f"198.51.100.{i}") for i, g in enumerate(guesses)]
            assert codes == [401] * LIMIT, codes
            # ...and the next guess at either is refused, her own tokens wait too (else trying the right one
            # would tell it apart), while bob is not held back.
            assert _me(proxy, second[:10] + "b9", "192.0.2.1") == 429
            assert _me(proxy, first, "192.0.2.2") == 429
            assert _me(proxy, bob, "192.0.2.3") == 200
    finally:
        server.stop()


def test_trusting_every_peer_is_refused_outside_dev(monkeypatch: Any) -> None:
    import pytest

    from robobpp.server.config import Settings
    from robobpp.server.connections import server_config

    secret = "a-strong-admin-token-0123456789"
    monkeypatch.delenv("FORWARDED_ALLOW_IPS", raising=False)
    assert server_config(Settings(env="prod", admin_token=secret))["forwarded_allow_ips"] == "127.0.0.1"
    proxies = Settings(env="prod", admin_token=secret, trusted_proxies="10.0.0.2, 172.18.0.0/16")
    assert server_config(proxies)["forwarded_allow_ips"] == "10.0.0.2, 172.18.0.0/16"
    with pytest.raises(ValueError, match="ROBOBPP_TRUSTED_PROXIES"):
        Settings(env="prod", admin_token=secret, trusted_proxies="*")
    monkeypatch.setenv("FORWARDED_ALLOW_IPS", "*")  # uvicorn's own variable, read when ours is unset
    with pytest.raises(ValueError, match="ROBOBPP_TRUSTED_PROXIES"):
        Settings(env="prod", admin_token=secret)
    assert server_config(Settings(env="dev"))["forwarded_allow_ips"] == "*"  # dev may


def test_healthz_answers_while_half_sent_connections_fill_the_server(tmp_path: Path) -> None:
    """Before: 2,000 half-sent connections from 20 addresses filled the 1,000-connection cap and ``/healthz``
    answered 503 for about 10 s. Here the cap is 40 (set like ``ROBOBPP_MAX_CONNECTIONS``), filled the same way
    from 4 addresses; ``/healthz`` is served from its reserve, anything else is refused at once."""
    import socket
    import time

    from tests.server.test_limits import _closed_within, _open, _server

    server = _server(
        tmp_path, max_connections=40, max_connections_per_client=0, header_timeout_s=30.0
    ).start()
    held: list[socket.socket] = []
    try:
        for i in range(60):  # 40 fill the server, 20 more are refused
            sock = _open(server, f"127.0.0.{2 + i % 4}")
            sock.sendall(b"GET /api/v1/leaderboards HTTP/1.1\r\nHost: x\r\nX-Slow: ")
            held.append(sock)
        time.sleep(0.5)
        started = time.monotonic()
        for _ in range(5):
            assert httpx.get(server.url + "/healthz", timeout=5).status_code == 200
        assert time.monotonic() - started < 3.0
        assert httpx.head(server.url + "/healthz", timeout=5).status_code in (200, 405)
        other = _open(server)  # anything else over the cap: 503 as soon as its first bytes show it
        other.sendall(b"GET /api/v1/leaderboards HTTP/1.1\r\nHost: x\r\n\r\n")
        closed, data = _closed_within(other, 2.0)
        assert closed and data.startswith(b"HTTP/1.1 503"), data
        silent = _open(server)  # and a connection that says nothing is let go after the probation
        closed, data = _closed_within(silent, 5.0)
        assert closed and data.startswith(b"HTTP/1.1 503"), data
    finally:
        for sock in held:
            sock.close()
        server.stop()
