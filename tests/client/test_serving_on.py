"""Servers say where they listen, and only once they do: a reader who connects at the line gets an answer.

``serve()`` (through ``examples/policy_server.py``) and ``robobpp serve`` are started as real processes; the
test reads their stdout until the line appears and then connects exactly once, without retrying.
"""

from __future__ import annotations

import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO

import httpx

from tests._orphans import with_parent_death
from tests.server.conftest import free_port, server_env

ROOT = Path(__file__).resolve().parents[2]


def _line_with(stream: IO[str], pattern: str, proc: subprocess.Popen[str], timeout: float) -> re.Match[str]:
    """The first stdout line matching ``pattern``, read in a thread so a silent process fails in ``timeout``."""
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        for line in iter(stream.readline, ""):
            lines.put(line)

    threading.Thread(target=pump, daemon=True).start()
    seen: list[str] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.2)
        except queue.Empty:
            if proc.poll() is not None and lines.empty():
                raise AssertionError(
                    f"the process ended (rc {proc.returncode}) before {pattern!r}: {seen}"
                ) from None
            continue
        seen.append(line)
        m = re.search(pattern, line)
        if m:
            return m
    raise AssertionError(f"no {pattern!r} within {timeout} s: {seen}")


def _start(cmd: list[str], **kw: object) -> subprocess.Popen[str]:
    return subprocess.Popen(
        with_parent_death(cmd), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw
    )  # type: ignore[call-overload]


def test_example_policy_server_prints_its_url_once_it_answers() -> None:
    """``--port 0``: the line names the port actually bound, and /info answers at once."""
    proc = _start(
        [sys.executable, str(ROOT / "examples" / "policy_server.py"), "--port", "0"],
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )
    try:
        assert proc.stdout is not None
        m = _line_with(
            proc.stdout, r"serving policy 'lowest-first' on (http://127\.0\.0\.1:(\d+)) ", proc, 60
        )
        assert int(m.group(2)) > 0
        info = httpx.get(m.group(1) + "/info", timeout=5)
        assert info.status_code == 200 and info.json()["protocol"] == "robobpp/1"
    finally:
        proc.terminate()
        proc.wait(10)


def test_policy_serve_cli_prints_the_url_once(tmp_path: Path) -> None:
    port = free_port()
    proc = _start(
        [sys.executable, "-m", "robobpp.cli", "policy", "serve", "dbl", "--port", str(port)],
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )
    try:
        assert proc.stdout is not None
        m = _line_with(proc.stdout, r"serving policy 'dbl' on (\S+) \(no secret", proc, 60)
        assert m.group(1) == f"http://127.0.0.1:{port}"
        assert httpx.get(m.group(1) + "/info", timeout=5).status_code == 200
    finally:
        proc.terminate()
        proc.wait(10)


def test_robobpp_serve_says_serving_on_only_once_it_accepts_connections(tmp_path: Path) -> None:
    """The start-up (migrations, baselines, worker processes) takes seconds; the line comes after it."""
    port = free_port()
    env = server_env(tmp_path, f"sqlite:///{tmp_path / 'robobpp.sqlite3'}", PYTHONPATH=str(ROOT))
    proc = _start(
        [sys.executable, "-m", "robobpp.cli", "serve", "--port", str(port)],
        env=env,
        cwd=tmp_path,
        start_new_session=True,
    )
    try:
        assert proc.stdout is not None
        m = _line_with(proc.stdout, r"robobpp: serving on (\S+) \(API docs (\S+)\)", proc, 90)
        assert m.group(1) == f"http://127.0.0.1:{port}" and m.group(2) == m.group(1) + "/docs"
        health = httpx.get(m.group(1) + "/healthz", timeout=10)  # one try: no retry hides an early line
        assert health.status_code == 200, health.text
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
