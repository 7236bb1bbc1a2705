"""Pull mode with several API processes: the two sockets of an episode meet through Redis.

- Two ``robobpp serve`` processes on one database: the participant's client connects to A only, the local
  workers (started by A) reach the relay on B only, so every pairing and every frame crosses processes. A
  submission completes; a client cut mid-episode comes back (to A) and the worker on B resumes the episode.
- ``robobpp serve --server-workers 2``: two API processes on one port, the worker pool started once, a pull
  submission evaluated and ranked.
- Without a broker, ``--server-workers 2`` is refused with a reason.

The two-process cases on one database run with Redis and with RabbitMQ as the relay's broker.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from robobpp.client.connect import connect
from robobpp.policies.dbl import DBL
from tests.server.conftest import (
    ADMIN_TOKEN,
    AMQP_URL,
    REDIS_URL,
    ServerProcess,
    SlowDBL,
    free_port,
    new_participant,
    rabbitmq_or_skip,
    redis_or_skip,
    server_env,
    wait_for,
)
from tests.server.test_pull import _cut_client_sockets, listening_ports

ROOT = Path(__file__).resolve().parents[2]


def _run_connect(server_url: str, token: str, policy: Any, **kwargs: Any) -> tuple[threading.Thread, dict]:
    result: dict[str, Any] = {"events": []}

    def run() -> None:
        result["sub"] = connect(
            policy,
            server_url,
            token,
            settings=["math"],
            on_event=result["events"].append,
            poll_s=0.3,
            **kwargs,
        )

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread, result


@pytest.fixture(
    params=[
        pytest.param("redis", marks=pytest.mark.redis),
        pytest.param("rabbitmq", marks=pytest.mark.rabbitmq),
    ]
)
def two_servers(request: pytest.FixtureRequest, tmp_path: Path) -> Any:
    """A (API + 2 local workers whose relay URL is B) and B (API only), one SQLite database, one broker."""
    if request.param == "redis":
        redis_or_skip()
    else:
        rabbitmq_or_skip()
    broker = REDIS_URL if request.param == "redis" else AMQP_URL
    db = f"sqlite:///{tmp_path / 'shared.sqlite3'}"
    port_b = free_port()
    common = {"ROBOBPP_PULL_BROKER_URL": broker, "ROBOBPP_EVALUATE_BASELINES": "0", "ROBOBPP_GROUPS": "1"}
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a_env = server_env(
        tmp_path / "a",
        db,
        ROBOBPP_PULL_RELAY_URL=f"http://127.0.0.1:{port_b}",
        ROBOBPP_PULL_RECONNECT_S="20",
        **common,
    )
    a = ServerProcess(a_env, tmp_path / "a").start()  # migrations and seeding done before B starts
    b = ServerProcess(
        server_env(tmp_path / "b", db, ROBOBPP_WORKERS="0", **common), tmp_path / "b", port=port_b
    )
    b.start()
    yield a, b
    for server in (a, b):
        server.crash()


def test_a_submission_completes_with_the_client_on_one_process_and_the_workers_on_another(
    two_servers: tuple[ServerProcess, ServerProcess],
) -> None:
    a, b = two_servers
    token = new_participant(a.client(), "split")
    thread, result = _run_connect(
        a.url, token, DBL, name="split", datasets=["diverse", "repetitive"], parallel=2
    )
    thread.join(timeout=150)
    assert not thread.is_alive(), result["events"]
    sub = result["sub"]
    assert (sub.mode, sub.status) == ("pull", "completed"), result["events"]
    episodes = b.client(token).get(f"/submissions/{sub.id}/episodes").json()
    assert len(episodes) == 2
    assert all(e["status"] == "done" and e["attempts"] == 1 for e in episodes), episodes
    assert all(e["termination"] == "completed" and e["boxes_placed"] > 5 for e in episodes), episodes
    # Every client socket was accepted by A, every worker socket by B (uvicorn logs each WebSocket accept).
    assert _accepted(a, "connect") and not _accepted(a, "episodes")
    assert _accepted(b, "episodes") and not _accepted(b, "connect")


def _accepted(server: ServerProcess, route: str) -> int:
    return server.log.read_text().count(f'"WebSocket /api/v1/pull/{route}')


def test_a_client_cut_mid_episode_resumes_with_the_worker_on_another_process(
    two_servers: tuple[ServerProcess, ServerProcess],
) -> None:
    a, _ = two_servers
    token = new_participant(a.client(), "flaky")
    thread, result = _run_connect(a.url, token, SlowDBL(), name="flaky", datasets=["repetitive"])
    api = a.client(token)
    sub_id = wait_for(lambda: next((s["id"] for s in api.get("/submissions").json()), None), timeout_s=30)
    wait_for(
        lambda: any(e["step"] >= 3 for e in api.get(f"/submissions/{sub_id}/episodes").json()), timeout_s=60
    )
    assert _cut_client_sockets(a.port) > 0
    thread.join(timeout=120)
    assert not thread.is_alive(), result["events"]
    assert result["sub"].status == "completed", result["events"]
    assert any("connection lost" in e for e in result["events"])
    (episode,) = api.get(f"/submissions/{sub_id}/episodes").json()
    assert episode["status"] == "done" and episode["attempts"] == 1
    assert episode["termination"] == "completed", episode["termination_detail"]
    assert episode["step"] == episode["boxes_total"] == episode["boxes_placed"]


@pytest.mark.redis
@pytest.mark.skipif(
    not Path("/proc/net/tcp").exists(), reason="reads /proc to tell API processes from workers"
)
def test_serve_with_two_api_processes_evaluates_and_ranks_a_pull_submission(tmp_path: Path) -> None:
    redis_or_skip()
    env = server_env(
        tmp_path,
        f"sqlite:///{tmp_path / 'n2.sqlite3'}",
        ROBOBPP_PULL_BROKER_URL=REDIS_URL,
        ROBOBPP_WORKERS="2",
    )
    server = ServerProcess(env, tmp_path, args=("--server-workers", "2")).start()
    try:
        assert server.proc is not None
        children = _children(server.proc.pid)
        api = [pid for pid in children if server.port in listening_ports(pid)]
        workers = [pid for pid in children if pid not in api and "resource_tracker" not in _cmdline(pid)]
        assert len(api) == 2, children  # two API processes accept on the one port
        # the pool of ROBOBPP_WORKERS=2 and the board worker, each started once, not once per API process
        assert len(workers) == 3, children
        assert httpx.get(server.url + "/healthz").json()["workers"] == 2  # the supervisor's pool, from either
        token = new_participant(server.client(), "two-procs")
        thread, result = _run_connect(
            server.url, token, DBL, name="two-procs", datasets=["diverse"], parallel=2
        )
        thread.join(timeout=150)
        assert not thread.is_alive(), result["events"]
        sub = result["sub"]
        assert sub.status == "completed", result["events"]
        board = server.client().get("/leaderboards/diverse/math").json()
        mine = next(e for e in board["entries"] if e["submission_id"] == sub.id)
        assert mine["rank"] >= 1 and mine["metrics"]["space_utilization"] > 0
        started = set(re.findall(r"Started server process \[(\d+)\]", server.log.read_text()))
        assert {int(p) for p in started} == set(api)
        # /metrics of whichever process answers counts the requests of both: 30 on fresh connections
        # (the kernel spreads them over the two processes), then every scrape sees all 30.
        for _ in range(30):
            assert httpx.get(server.url + "/api/v1/leaderboards").status_code == 200
        time.sleep(1.2)  # each process re-renders its request metrics at most once a second
        for _ in range(4):
            text = httpx.get(server.url + "/metrics", headers={"Authorization": f"Bearer {ADMIN_TOKEN}"}).text
            counted = re.search(
                r'robobpp_http_requests_total\{method="GET",route="/api/v1/leaderboards",status="200"\} (\S+)',
                text,
            )
            assert counted is not None and float(counted.group(1)) == 30, text[-2000:]
    finally:
        server.stop()
    assert server.proc.returncode == 0
    # every child goes with it (the resource tracker a moment after the supervisor)
    wait_for(lambda: not any(_alive(pid) for pid in children), timeout_s=15, every_s=0.2)


@pytest.mark.redis
@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads /proc to find the API processes")
def test_an_api_process_killed_mid_episode_is_replaced_and_the_episode_resumes(tmp_path: Path) -> None:
    """kill -9 of one of two API processes mid-episode: the supervisor starts a new one, and the episode goes on
    and is counted once whatever the killed process held (the kernel decides where each socket lands: the
    client's, the worker's, both or neither; the next test kills the client's process on purpose)."""
    redis_or_skip()
    env = server_env(
        tmp_path,
        f"sqlite:///{tmp_path / 'kill.sqlite3'}",
        ROBOBPP_PULL_BROKER_URL=REDIS_URL,
        ROBOBPP_EVALUATE_BASELINES="0",
        ROBOBPP_GROUPS="1",
        ROBOBPP_PULL_RECONNECT_S="20",
    )
    server = ServerProcess(env, tmp_path, args=("--server-workers", "2")).start()
    try:
        assert server.proc is not None
        token = new_participant(server.client(), "unlucky")
        thread, result = _run_connect(server.url, token, SlowDBL(), name="unlucky", datasets=["repetitive"])
        api = server.client(token)
        sub_id = wait_for(lambda: next((s["id"] for s in api.get("/submissions").json()), None), timeout_s=30)
        wait_for(
            lambda: any(e["step"] >= 3 for e in api.get(f"/submissions/{sub_id}/episodes").json()),
            timeout_s=60,
        )
        before = [pid for pid in _children(server.proc.pid) if server.port in listening_ports(pid)]
        assert len(before) == 2
        os.kill(before[0], signal.SIGKILL)
        thread.join(timeout=120)
        assert not thread.is_alive(), result["events"]
        assert result["sub"].status == "completed", result["events"]
        (episode,) = api.get(f"/submissions/{sub_id}/episodes").json()
        assert episode["status"] == "done" and episode["attempts"] == 1, episode
        assert episode["termination"] == "completed", episode["termination_detail"]
        assert episode["step"] == episode["boxes_total"] == episode["boxes_placed"]
        after = [pid for pid in _children(server.proc.pid) if server.port in listening_ports(pid)]
        assert len(after) == 2 and before[0] not in after  # the supervisor replaced the killed one
    finally:
        server.stop()


@pytest.mark.parametrize(
    "broker",
    [pytest.param("redis", marks=pytest.mark.redis), pytest.param("rabbitmq", marks=pytest.mark.rabbitmq)],
)
def test_the_worker_hears_gone_when_the_client_s_api_process_dies_and_resumes_on_its_return(
    tmp_path: Path, broker: str
) -> None:
    """The client's API process (B) is killed while the worker, on A, waits for an answer. Nothing will ever come
    from B's side, and nothing tells the worker's side but B's silence: its liveness check (B's channel has no
    subscriber left) closes the worker's socket with GONE within seconds, long before the 10 s step deadline.
    B comes back on its port, the client reconnects, and the episode resumes where it was."""
    if broker == "redis":
        redis_or_skip()
    else:
        rabbitmq_or_skip()
    db = f"sqlite:///{tmp_path / 'die.sqlite3'}"
    common = {
        "ROBOBPP_PULL_BROKER_URL": REDIS_URL if broker == "redis" else AMQP_URL,
        "ROBOBPP_EVALUATE_BASELINES": "0",
        "ROBOBPP_GROUPS": "1",
    }
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a_env = server_env(
        tmp_path / "a", db, ROBOBPP_PULL_RECONNECT_S="60", ROBOBPP_STEP_TIMEOUT_S="10", **common
    )
    a = ServerProcess(a_env, tmp_path / "a").start()  # API + local workers, whose relay is A itself
    b = ServerProcess(
        server_env(tmp_path / "b", db, ROBOBPP_WORKERS="0", **common), tmp_path / "b", port=free_port()
    )
    b.start()
    try:
        token = new_participant(a.client(), "orphaned")
        policy = SlowDBL()
        policy.delay_s = 1.0  # the worker spends most of each step waiting for the answer
        thread, result = _run_connect(b.url, token, policy, name="orphaned", datasets=["repetitive"])
        api = a.client(token)
        sub_id = wait_for(lambda: next((s["id"] for s in api.get("/submissions").json()), None), timeout_s=30)
        wait_for(
            lambda: any(e["step"] >= 2 for e in api.get(f"/submissions/{sub_id}/episodes").json()),
            timeout_s=60,
        )
        b.crash()
        b.start()  # same port: the client's reconnection lands on the new B
        thread.join(timeout=150)
        assert not thread.is_alive(), result["events"]
        assert result["sub"].status == "completed", result["events"]
        (episode,) = api.get(f"/submissions/{sub_id}/episodes").json()
        assert episode["status"] == "done" and episode["attempts"] == 1, episode
        assert episode["termination"] == "completed", episode["termination_detail"]
        assert episode["step"] == episode["boxes_total"] == episode["boxes_placed"]
    finally:
        for server in (a, b):
            server.crash()


def test_several_api_processes_without_a_broker_are_refused_with_the_reason(tmp_path: Path) -> None:
    env = {**server_env(tmp_path, f"sqlite:///{tmp_path / 'x.sqlite3'}"), "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-m", "robobpp.cli", "serve", "--server-workers", "2", "--port", str(free_port())],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2, done.stderr
    assert "--server-workers 2 needs a broker" in done.stderr and "ROBOBPP_PULL_BROKER_URL" in done.stderr
    assert not (tmp_path / "x.sqlite3").exists()  # refused before anything was written


def _children(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return sorted(found)


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""
