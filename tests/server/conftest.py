"""Server test fixtures: a real ``robobpp serve`` subprocess and policy servers built with the SDK (the fresh
databases, ``db_url`` and ``pg_url``, are tests/conftest.py's)."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from robobpp.core import Action, Observation
from robobpp.db import work
from robobpp.db.models import Participant
from robobpp.db.session import transaction
from robobpp.policies.dbl import DBL
from tests._orphans import with_parent_death

ADMIN_TOKEN = "test-admin-token-0123456789abcdef"
REDIS_URL = os.environ.get("ROBOBPP_TEST_REDIS", "redis://127.0.0.1:6379/0")
AMQP_URL = os.environ.get("ROBOBPP_TEST_AMQP", "amqp://guest:guest@127.0.0.1:5672//")
OFFLINE = "robobpp.worker.specs:offline_spec"
#: The secret the policy servers of these fixtures check.
POLICY_SECRET = "policy-secret-123"
_ROOT = Path(__file__).resolve().parents[2]


def redis_or_skip() -> None:
    """Skip (saying why) when the machine's Redis does not answer."""
    import redis

    try:
        redis.Redis.from_url(REDIS_URL, socket_connect_timeout=2).ping()
    except redis.RedisError as exc:
        pytest.skip(f"Redis is not reachable at {REDIS_URL}: {exc}")


def rabbitmq_or_skip() -> None:
    """Skip (saying why) when the machine's RabbitMQ does not answer."""
    import amqp

    from robobpp.server.relay_amqp import connection_options

    try:
        connection = amqp.Connection(**connection_options(AMQP_URL))
        connection.connect()
        connection.close()
    except Exception as exc:  # noqa: BLE001 - any failure to connect means "not here"
        pytest.skip(f"RabbitMQ is not reachable at {AMQP_URL}: {exc}")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerProcess:
    """``robobpp serve`` in a subprocess (real uvicorn, real worker processes)."""

    def __init__(
        self, env: dict[str, str], data_dir: Path, args: tuple[str, ...] = (), port: int | None = None
    ) -> None:
        self.env = env
        self.data_dir = data_dir
        self.args = args
        self.fixed_port = port
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen[bytes] | None = None
        self.log = data_dir / "server.log"

    def start(self) -> ServerProcess:
        self.port = self.fixed_port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        cmd = [
            sys.executable,
            "-c",
            "from robobpp.cli import main; main()",
            "serve",
            "--port",
            str(self.port),
            *self.args,
        ]
        out = self.log.open("ab")
        # Own session: a crash test can kill the server and its worker processes at once (killpg).
        self.proc = subprocess.Popen(
            with_parent_death(cmd),
            env=self.env,
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=self.data_dir,
            start_new_session=True,
        )
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited: {self.log.read_text()[-3000:]}")
            try:
                if httpx.get(self.url + "/healthz", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.3)
        raise RuntimeError(f"server did not start: {self.log.read_text()[-3000:]}")

    def crash(self) -> None:
        """SIGKILL the server and every worker process it started, mid-whatever."""
        assert self.proc is not None
        with contextlib.suppress(ProcessLookupError):  # already gone
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        if sig == signal.SIGKILL:
            self.crash()
            return
        self.proc.send_signal(sig)
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)

    def client(self, token: str = ADMIN_TOKEN) -> httpx.Client:
        return httpx.Client(
            base_url=self.url + "/api/v1", headers={"Authorization": f"Bearer {token}"}, timeout=30
        )


def server_env(state_dir: Path, db: str, **extra: str) -> dict[str, str]:
    """The environment of a test server: offline episodes, 2 groups, Math only, short leases, loopback
    policy URLs allowed, nothing inherited from the caller's ``ROBOBPP_*`` (also used by tests/client)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROBOBPP_")}
    env.update(
        {
            "ROBOBPP_STATE_DIR": str(state_dir),
            "ROBOBPP_DATABASE_URL": db,
            "ROBOBPP_ADMIN_TOKEN": ADMIN_TOKEN,
            "ROBOBPP_ALLOW_PRIVATE_POLICY_URLS": "1",
            "ROBOBPP_SPEC_PROVIDER": OFFLINE,
            "ROBOBPP_GROUPS": "2",
            "ROBOBPP_BOARD_REFRESH_S": "0",  # tests read a board right after a submission finishes
            "ROBOBPP_SETTINGS": '["math"]',
            "ROBOBPP_WORKERS": "2",
            "ROBOBPP_LEASE_S": "4",
            "ROBOBPP_POLL_INTERVAL_S": "0.2",
            "ROBOBPP_BASELINES": '["dbl"]',
        }
    )
    env.update(extra)
    return env


@pytest.fixture
def make_server(tmp_path: Path) -> Iterator[Callable[..., ServerProcess]]:
    started: list[ServerProcess] = []

    def factory(db: str, **extra: str) -> ServerProcess:
        server = ServerProcess(server_env(tmp_path, db, **extra), tmp_path)
        started.append(server)
        return server.start()

    yield factory
    for s in started:
        s.stop(signal.SIGKILL)


@pytest.fixture
def own_process() -> Iterator[Callable[[str], str]]:
    """Serve a policy (``module:Class``) in a process of its own, as a participant does: two participants'
    servers in the test's process would wait for each other's interpreter lock, which no deployment does."""
    started: list[subprocess.Popen[str]] = []

    def start(policy: str) -> str:
        module, cls = policy.split(":")
        code = (
            f"from robobpp.client.serve import serve; from {module} import {cls}; "
            f"serve({cls}(), port=0, secret={POLICY_SECRET!r})"
        )
        proc = subprocess.Popen(
            with_parent_death([sys.executable, "-c", code]), stdout=subprocess.PIPE, text=True, cwd=_ROOT
        )
        started.append(proc)
        assert proc.stdout is not None
        return proc.stdout.readline().split(" on ")[1].split(" ")[0]  # the line says where it listens

    yield start
    for proc in started:
        proc.terminate()
        proc.wait(10)


class SlowDBL(DBL):
    """DBL that thinks for a while, so a test can act while an episode runs."""

    delay_s = 0.4

    def act(self, obs: Observation) -> Action | None:
        time.sleep(self.delay_s)
        return super().act(obs)


@pytest.fixture
def policy_server() -> Iterator[Callable[..., Any]]:
    from robobpp.client.serve import BackgroundServer, create_policy_app

    servers: list[Any] = []

    def factory(policy: Any = DBL, secret: str | None = "policy-secret-123") -> Any:
        srv = BackgroundServer(create_policy_app(policy, secret)).start()
        servers.append(srv)
        return srv

    yield factory
    for s in servers:
        s.stop()


def wait_for(predicate: Callable[[], Any], timeout_s: float = 120, every_s: float = 0.3) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(every_s)
    raise AssertionError("condition not reached in time")


def db_rows(url: str, sql: str, **params: Any) -> list[Any]:
    """Read the record of truth directly (what the API does not show: worker ids, leases)."""
    from sqlalchemy import create_engine, text

    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            return list(conn.execute(text(sql), params).all())
    finally:
        engine.dispose()


def submit_direct(
    app: Any,
    participant: str,
    url: str,
    *,
    datasets: tuple[str, ...],
    groups: int,
    name: str | None = None,
    lookahead: int = 0,
) -> int:
    """A Math-setting submission written straight into the app's database (no HTTP, no quota), for tests
    that need many entries quickly; the participant is created on first use."""
    with app.state.runtime.session() as s:
        p = s.execute(select(Participant).where(Participant.name == participant)).scalar_one_or_none()
        if p is None:
            p = Participant(name=participant)
            s.add(p)
            s.flush()
        return work.create_submission(
            s,
            p,
            name=name or participant,
            policy_url=url,
            datasets=list(datasets),
            settings=["math"],
            groups=groups,
            lookahead=lookahead,
        ).id


def new_participant(client: httpx.Client, name: str = "alice") -> str:
    r = client.post("/participants", json={"name": name})
    assert r.status_code == 201, r.text
    return r.json()["token"]


def complete_next_episode(
    factory: sessionmaker[Session], metrics: dict[str, float], **result: Any
) -> work.Claim:
    """Claim the next episode as worker "w" and record it completed, 3 boxes of 3, with ``metrics`` (and any other
    ``result`` fields), as a worker would: for tests that need finished runs without running a policy."""
    with transaction(factory) as s:
        claim = work.claim_episode(s, "w", lease_s=10, max_attempts=3)
        assert claim is not None
        recorded = {
            "termination": "completed",
            "termination_detail": "",
            "boxes_total": 3,
            "boxes_placed": 3,
            "metrics": metrics,
            "counters": {},
            "steps": [],
        } | result
        assert work.complete_episode(s, claim.episode_id, claim.token, recorded, keep_trace=False)
    return claim
