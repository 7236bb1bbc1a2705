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
