"""The compose stack on a real Docker daemon: a daemon that leaves the host's firewall alone, the images that
deploy/build-images.sh built, host networking on free loopback ports.

Skips, saying why, where Docker cannot run it: no docker/docker-compose/dockerd, no daemon and no root to start
one, a daemon that does not start, or images that are absent or were built from other sources (building them
takes minutes, so the test never builds: run ``deploy/build-images.sh``). A daemon the fixture started is stopped
at the end, and everything the stack created (containers, volumes) is removed.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest

from deploy.source_hash import source_hash
from tests.server.conftest import free_port

ROOT = Path(__file__).resolve().parents[2]
TAG = "debian"
IMAGES = (f"robobpp:{TAG}", f"robobpp-postgres:{TAG}", f"robobpp-redis:{TAG}")
FILES = ("docker-compose.yml", "deploy/compose.debian.yml", "deploy/compose.host-network.yml")
SERVICES = ("postgres", "redis", "server", "worker")


def _run(*argv: str, timeout: float = 120, check: bool = True, env: dict[str, str] | None = None) -> str:
    proc = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env)
    if check and proc.returncode != 0:
        raise RuntimeError(
            f"{' '.join(argv)} exited {proc.returncode}:\n{proc.stdout[-2000:]}{proc.stderr[-3000:]}"
        )
    return proc.stdout


def _daemon_answers() -> bool:
    return subprocess.run(["docker", "info"], capture_output=True, timeout=30).returncode == 0


@pytest.fixture(scope="session")
def docker_daemon() -> Iterator[None]:
    """A daemon that answers; started here (and stopped at the end) when none runs."""
    for tool in ("docker", "docker-compose"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not installed (Debian: apt-get install docker.io docker-compose)")
    started = False
    if not _daemon_answers():
        if shutil.which("dockerd") is None or os.geteuid() != 0:
            pytest.skip("no Docker daemon answers, and starting one needs root and dockerd (docker.io)")
        proc = subprocess.run(
            [str(ROOT / "deploy/dockerd.sh"), "start"], capture_output=True, text=True, timeout=120
        )
        if proc.returncode != 0:
            pytest.skip(
                f"the Docker daemon did not start here: {(proc.stdout + proc.stderr).strip()[-1500:]}"
            )
        started = True
    try:
        yield
    finally:
        if started:
            subprocess.run([str(ROOT / "deploy/dockerd.sh"), "stop"], capture_output=True, timeout=120)


@pytest.fixture(scope="session")
def built_images(docker_daemon: None) -> None:
    missing = [
        i for i in IMAGES if subprocess.run(["docker", "image", "inspect", i], capture_output=True).returncode
    ]
    if missing:
        pytest.skip(
            f"images {', '.join(missing)} are absent: build them with deploy/build-images.sh (minutes)"
        )
    label = _run(
        "docker", "image", "inspect", "--format", '{{index .Config.Labels "org.robobpp.source"}}', IMAGES[0]
    )
    if label.strip() != source_hash():
        pytest.skip(
            f"{IMAGES[0]} was built from other sources ({label.strip() or 'no label'} != {source_hash()}): "
            "rebuild it with deploy/build-images.sh"
        )


@dataclass
class Stack:
    """One compose project on host networking; ``compose(...)`` runs docker-compose on it."""

    project: str
    env_file: Path
    ports: dict[str, int]
    admin: str
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.ports['ROBOBPP_PORT']}"

    def compose(self, *args: str, timeout: float = 300) -> str:
        argv = [
            "docker-compose",
            *(a for f in FILES for a in ("-f", f)),
            "--env-file",
            str(self.env_file),
            "-p",
            self.project,
            *args,
        ]
        # Only the env file configures the stack: a variable of the calling shell would win over it.
        env = {k: v for k, v in os.environ.items() if k in ("PATH", "HOME", "DOCKER_HOST", "LANG")}
        return _run(*argv, timeout=timeout, env=env)

    def containers(self, service: str) -> list[str]:
        return self.compose("ps", "-q", service).split()

    def health(self) -> dict[str, str]:
        """``name: status`` of every container of the project (health status, else its state)."""
        ids = self.compose("ps", "-q").split()
        if not ids:
            return {}
        out = _run("docker", "inspect", *ids)
        return {
            c["Name"].lstrip("/"): (c["State"].get("Health") or {}).get("Status", c["State"]["Status"])
            for c in json.loads(out)
        }

    def logs(self, service: str | None = None, tail: str = "60") -> str:
        try:
            return self.compose(
                "logs", "--no-color", "--tail", tail, *([service] if service else []), timeout=60
            )
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            return f"(no logs: {exc})"

    def wait_healthy(self, workers: int, timeout: float = 600) -> float:
        """Seconds until postgres, redis, the server and ``workers`` workers all report healthy."""
        t0 = time.monotonic()
        deadline = t0 + timeout
        while time.monotonic() < deadline:
            status = self.health()
            if len(status) == 3 + workers and all(s == "healthy" for s in status.values()):
                return time.monotonic() - t0
            time.sleep(1)
        pytest.fail(f"the stack was not healthy within {timeout:.0f} s: {self.health()}\n{self.logs()}")

    def api(self, method: str, path: str, token: str | None = None, **kw: Any) -> Any:
        headers = {"Authorization": f"Bearer {token or self.admin}"}
        r = httpx.request(method, self.url + "/api/v1" + path, headers=headers, timeout=30, **kw)
        assert r.status_code < 300, f"{method} {path}: {r.status_code} {r.text[:500]}"
        return r.json()


@pytest.fixture
def stack(built_images: None, tmp_path: Path) -> Iterator[Stack]:
    ports = {name: free_port() for name in ("POSTGRES_PORT", "REDIS_PORT", "ROBOBPP_PORT")}
    admin = secrets.token_urlsafe(24)
    settings = {
        "POSTGRES_PASSWORD": secrets.token_urlsafe(18),
        "REDIS_PASSWORD": secrets.token_urlsafe(18),
        "ROBOBPP_ADMIN_TOKEN": admin,
        **{k: str(v) for k, v in ports.items()},
        # Small: three groups, one episode at a time per worker, no baselines to evaluate.
        "ROBOBPP_GROUPS": "3",
        "ROBOBPP_EVALUATE_BASELINES": "0",
        "ROBOBPP_WORKER_CONCURRENCY": "1",
    }
    env_file = tmp_path / "stack.env"
    env_file.write_text("".join(f"{k}={v}\n" for k, v in settings.items()))
    env_file.chmod(0o600)
    s = Stack(project=f"robobpp-smoke-{os.getpid()}", env_file=env_file, ports=ports, admin=admin)
    try:
        yield s
    finally:
        (tmp_path / "compose.log").write_text(s.logs())
        s.compose("down", "-v", "--remove-orphans", timeout=300)
