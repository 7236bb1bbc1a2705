"""The compose stack's environment without Docker: the same ``x-robobpp-env`` settings (lease, attempts,
timeouts, ``ROBOBPP_ENV=prod``) and the same processes (``robobpp serve`` with no local pool, ``robobpp
worker``), on this machine's PostgreSQL and Redis. Only the service addresses, the paths, the synthetic spec
provider, one group and no baselines differ — each listed in :func:`compose_env`.

It shows two properties of the shipped settings: a server restart sends nothing that is already queued,
and a worker killed with ``kill -9`` mid-episode has its episode back in the queue within 30 s.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import select

from robobpp.db.models import EpisodeRow
from tests.celery.conftest import ROOT, Fleet, episodes, new_submission, submission_status, wait_for
from tests.celery.test_deploy_files import _compose, _substitute

pytestmark = [pytest.mark.postgres, pytest.mark.redis]
ADMIN = "compose-admin-token-0123456789abcdef"
REQUEUE_BOUND_S = 30.0  # the requirement for the shipped settings


def compose_env(fleet: Fleet, tmp: Path) -> dict[str, str]:
    env = {k: _substitute(str(v)) for k, v in _compose()["x-robobpp-env"].items()}
    shipped = dict(env)
    env.update(
        {
            "ROBOBPP_DATABASE_URL": fleet.env[
                "ROBOBPP_DATABASE_URL"
            ],  # this machine's services, not compose's
            "ROBOBPP_BROKER_URL": fleet.env["ROBOBPP_BROKER_URL"],
            "ROBOBPP_CELERY_QUEUE": fleet.env["ROBOBPP_CELERY_QUEUE"],
            "ROBOBPP_STATE_DIR": str(tmp / "data"),
            "ROBOBPP_DATA_DIR": os.environ.get(
                "ROBOBPP_TEST_DATA_DIR", str(Path.home() / ".cache" / "robobpp")
            ),
            "ROBOBPP_PRIVATE_DIR": str(tmp / "private"),
            "ROBOBPP_SPEC_PROVIDER": "tests.celery.helpers:spec",
            "ROBOBPP_GROUPS": "1",
            "ROBOBPP_EVALUATE_BASELINES": "0",
        }
    )
    for key in ("ROBOBPP_ENV", "ROBOBPP_LEASE_S", "ROBOBPP_MAX_ATTEMPTS", "ROBOBPP_EPISODE_TIMEOUT_S"):
        assert env[key] == shipped[key]  # the settings under test are compose's own
    base = {k: v for k, v in os.environ.items() if not k.startswith("ROBOBPP_")}
    return {**base, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""), **env}


def start_server(env: dict[str, str], tmp: Path) -> tuple[subprocess.Popen[bytes], str]:
    from tests.server.conftest import free_port

    port = free_port()
    compose = _compose()
    # robobpp's own settings of the server (TRUSTED_PROXIES is for a proxy in front: the default here)
    own = {
        k: str(v)
        for k, v in compose["services"]["server"]["environment"].items()
        if k.startswith("ROBOBPP_")
        and k not in compose["x-robobpp-env"]
        and k not in ("ROBOBPP_ADMIN_TOKEN", "ROBOBPP_TRUSTED_PROXIES")
    }
    assert own == {"ROBOBPP_WORKERS": "0"}  # the server runs no episodes itself; the workers do
    server_env = {**env, **own, "ROBOBPP_ADMIN_TOKEN": ADMIN}
    log = (tmp / "server.log").open("ab")
    proc = subprocess.Popen(
        [sys.executable, "-c", "from robobpp.cli import main; main()", "serve", "--port", str(port)],
        env=server_env,
        cwd=ROOT,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    url = f"http://127.0.0.1:{port}"

    def up() -> bool:
        if proc.poll() is not None:
            pytest.fail("server exited: " + (tmp / "server.log").read_text()[-3000:])
        try:
            return httpx.get(url + "/healthz", timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    wait_for(up, 120, "the server", lambda: (tmp / "server.log").read_text()[-3000:])
    return proc, url


def queued(fleet: Fleet) -> int:
    from kombu.connection import Connection

    with Connection(fleet.env["ROBOBPP_BROKER_URL"]) as conn:  # kombu's Redis client: the queue is a list
        return int(conn.default_channel.client.llen(fleet.env["ROBOBPP_CELERY_QUEUE"]))


@pytest.mark.parametrize("broker", ["redis"], indirect=True)
def test_compose_settings_restart_and_kill_9(fleet: Fleet, factory: Any, tmp_path: Path) -> None:
    env = compose_env(fleet, tmp_path)
    fleet.env = env
    sub = new_submission(
        factory,
        policy="tests.celery.helpers:SlowDBL",
        datasets=["repetitive"],
        groups=3,
        name=f"compose-{env['ROBOBPP_CELERY_QUEUE']}",
    )
    server, _url = start_server(env, tmp_path)
    try:
        wait_for(lambda: queued(fleet) == 3, 60, "the three episodes to be queued", fleet.logs)
        # A server restart sends nothing already queued (it used to send every pending episode again).
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(30)
        server, _url = start_server(env, tmp_path)
        time.sleep(3)  # several dispatch rounds (every 0.5 s)
        assert queued(fleet) == 3

        fleet.start(2, concurrency=1)

        def running() -> EpisodeRow | None:
            rows = [r for r in episodes(factory, sub) if r.status == "running" and r.step >= 2]
            return rows[0] if rows else None

        row = wait_for(running, 120, "an episode mid-way", fleet.logs)
        victim = next(p for p in fleet.procs if p.pid == os.getpgid(int(row.worker.rsplit(":", 1)[1])))
        fleet.kill(victim)
        killed = time.monotonic()

        def requeued() -> bool:
            with factory() as s:
                ep = s.execute(select(EpisodeRow).where(EpisodeRow.id == row.id)).scalar_one()
            return ep.status == "pending" or ep.attempts >= 2

        wait_for(requeued, 120, "the killed worker's episode to be re-queued", fleet.logs)
        waited = time.monotonic() - killed
        print(f"episode re-queued {waited:.1f} s after kill -9 (lease {env['ROBOBPP_LEASE_S']} s)")
        assert waited < REQUEUE_BOUND_S, f"{waited:.1f} s with lease {env['ROBOBPP_LEASE_S']} s"
        wait_for(lambda: submission_status(factory, sub) == "completed", 180, "the submission", fleet.logs)
        rows = episodes(factory, sub)
        assert all(r.status == "done" for r in rows)
        assert sorted(r.attempts for r in rows) == [1, 1, 2]  # one retry, nothing counted twice
    finally:
        os.killpg(server.pid, signal.SIGKILL)
        server.wait(10)
