"""Limits on connections (real server, real sockets): a header deadline, a body deadline, caps on open
connections overall and per client address, and caps on pull-mode client connections per submission and per
participant. Before them, 4,000 half-headers all stayed open after 60 s and one participant opened 1,000 idle
pull connections in 4.6 s."""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect as ws_connect

from robobpp.client.serve import BackgroundServer
from robobpp.db.migrate import upgrade
from robobpp.server.app import create_app
from robobpp.server.config import Settings
from robobpp.server.connections import server_config

ADMIN = "limits-admin-token-0123456789abcdef"


def _server(tmp: Path, **limits: Any) -> BackgroundServer:
    db = f"sqlite:///{tmp / 'limits.sqlite3'}"
    upgrade(db)
    settings = Settings(
        database_url=db,
        admin_token=ADMIN,
        state_dir=tmp,
        workers=0,
        groups=1,
        settings=("math",),
        evaluate_baselines=False,
        **limits,
    )
    return BackgroundServer(create_app(settings, start_workers=False), **server_config(settings))


@pytest.fixture
def serve(tmp_path: Path) -> Iterator[Any]:
    started: list[BackgroundServer] = []

    def start(**limits: Any) -> BackgroundServer:
        server = _server(tmp_path, **limits).start()
        started.append(server)
        return server

    yield start
    for server in started:
        server.stop()


def _open(server: BackgroundServer, source: str = "127.0.0.1") -> socket.socket:
    sock = socket.create_connection((server.host, server.port), timeout=10, source_address=(source, 0))
    return sock


def _closed_within(sock: socket.socket, seconds: float) -> tuple[bool, bytes]:
    """Whether the server closed ``sock`` within ``seconds``, and what it sent before."""
    sock.settimeout(seconds)
    data = b""
    try:
        while chunk := sock.recv(4096):
            data += chunk
    except TimeoutError:
        return False, data
    except ConnectionResetError:
        pass
    return True, data


def test_half_a_header_is_cut_off_at_the_header_deadline(serve) -> None:
    server = serve(header_timeout_s=1.0)
    silent = _open(server)
    half = _open(server)
    half.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: ")
    started = time.monotonic()
    for sock in (silent, half):
        closed, data = _closed_within(sock, 5.0)
        assert closed and data == b"", data
    assert time.monotonic() - started < 3.0
    # A prompt request on a kept-alive connection is served, and the next one gets its own deadline.
    ok = _open(server)
    ok.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
    ok.settimeout(5)
    assert ok.recv(4096).startswith(b"HTTP/1.1 200")
    ok.sendall(b"GET /healthz HTTP/1.1\r\nHo")
    closed, _ = _closed_within(ok, 5.0)
    assert closed
    assert httpx.get(server.url + "/healthz", timeout=10).status_code == 200


def test_a_dripped_body_is_answered_408_at_the_body_deadline(serve) -> None:
    server = serve(body_timeout_s=1.0, header_timeout_s=30.0)
    sock = _open(server)
    sock.sendall(
        b"POST /api/v1/participants HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer "
        + ADMIN.encode()
        + b'\r\nContent-Type: application/json\r\nContent-Length: 100\r\n\r\n{"na'
    )
    started = time.monotonic()
    closed, data = _closed_within(sock, 10.0)
    assert data.startswith(b"HTTP/1.1 408"), data
    assert b"body-timeout" in data and time.monotonic() - started < 5.0


def test_open_connections_are_capped_per_client_address_and_overall(serve) -> None:
    server = serve(max_connections=6, max_connections_per_client=3, header_timeout_s=30.0)
    mine = [_open(server) for _ in range(3)]
    time.sleep(0.3)
    refused = _open(server)
    closed, data = _closed_within(refused, 5.0)
    assert closed and data.startswith(b"HTTP/1.1 503") and b"retry-after: 5" in data, data
    # Another address is not held back by this one's connections...
    other = [_open(server, "127.0.0.2") for _ in range(3)]
    time.sleep(0.3)
    assert not _closed_within(other[0], 0.5)[0]
    # ...until the server as a whole is full.
    third = _open(server, "127.0.0.3")
    closed, data = _closed_within(third, 5.0)
    assert closed and data.startswith(b"HTTP/1.1 503"), data
    for sock in mine:
        sock.close()
    time.sleep(0.3)
    assert httpx.get(server.url + "/healthz", timeout=10).status_code == 200  # freed slots serve again
    for sock in other:
        sock.close()


def _pull_submission(server: BackgroundServer, token: str, name: str) -> int:
    mine = httpx.Client(base_url=server.url + "/api/v1", headers={"Authorization": f"Bearer {token}"})
    made = mine.post("/submissions", json={"name": name, "mode": "pull", "datasets": ["diverse"]})
    assert made.status_code == 201, made.text
    return int(made.json()["id"])


def _pull(server: BackgroundServer, token: str, submission: int) -> Any:
    url = server.url.replace("http", "ws") + f"/api/v1/pull/connect?submission={submission}"
    ws = ws_connect(url, additional_headers={"Authorization": f"Bearer {token}"}, open_timeout=10)
    try:
        hello = json.loads(ws.recv(timeout=5))
    except ConnectionClosed as exc:
        ws.close()
        return exc.rcvd.code if exc.rcvd else None
    assert hello["type"] == "welcome"
    return ws


def test_pull_connections_are_capped_per_submission_and_per_participant(serve) -> None:
    server = serve(pull_max_per_submission=2, pull_max_per_participant=3, quota_concurrent=5)
    admin = httpx.Client(base_url=server.url + "/api/v1", headers={"Authorization": f"Bearer {ADMIN}"})
    token = admin.post("/participants", json={"name": "flooder"}).json()["token"]
    other = admin.post("/participants", json={"name": "other"}).json()["token"]
    first, second = _pull_submission(server, token, "a"), _pull_submission(server, token, "b")
    theirs = _pull_submission(server, other, "c")
    held = [_pull(server, token, first), _pull(server, token, first)]
    assert _pull(server, token, first) == 4029  # the submission's cap
    held.append(_pull(server, token, second))
    assert _pull(server, token, second) == 4029  # the participant's cap (3), though the submission has room
    held.append(_pull(server, other, theirs))  # another participant is not held back
    assert not isinstance(held[-1], int)
    held.pop(0).close()
    time.sleep(0.3)
    again = _pull(server, token, second)  # a slot freed by closing one
    assert not isinstance(again, int)
    for ws in [*held, again]:
        ws.close()
