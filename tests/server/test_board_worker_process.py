"""The board worker process ends with its API process, even in the middle of a computation: an API process
killed outright (SIGKILL, the OOM killer) left it computing to the end of its pass (minutes and gigabytes at
100,000 submissions), renewing its claim on the track meanwhile.

This checks the portable guard (a thread watching the parent's id, worker/lifeline.py) without the kernel's
signal, which tests/server/test_supervisor_death.py sees at work."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from robobpp.boards import worker as board_worker
from robobpp.worker.lifeline import Lifeline


def _busy_pass(self: board_worker.BoardWorker) -> list[str]:
    """A pass that computes for a long time (Python holding the GIL, as the engine's work does)."""
    Path(os.environ["BUSY_FLAG"]).write_text("computing")
    end = time.monotonic() + 120
    while time.monotonic() < end:
        sum(range(10_000))
    return []


def _worker_main(url: str, parent: int, flag: str) -> None:
    os.environ["BUSY_FLAG"] = flag
    board_worker.BoardWorker.run_once = _busy_pass  # type: ignore[method-assign]
    lifeline = Lifeline(parent, kernel=False)  # the portable guard alone
    board_worker._process_main(url, ("diverse",), ("math",), {}, SimpleNamespace(value=0), lifeline)


def _api_process(url: str, flag: str, pids: Any) -> None:
    """Stands in for the API process: starts a board worker process, then waits to be killed."""
    context = multiprocessing.get_context("spawn")
    child = context.Process(target=_worker_main, args=(url, os.getpid(), flag))
    child.start()
    pids.put(child.pid)
    time.sleep(300)


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    return "\nState:\tZ" not in state  # a zombie has ended (its new parent reaps it when it does)


def test_a_board_worker_process_ends_mid_computation_when_its_api_process_is_killed(tmp_path: Path) -> None:
    context = multiprocessing.get_context("spawn")
    pids = context.Queue()
    flag = tmp_path / "computing"
    api = context.Process(target=_api_process, args=(f"sqlite:///{tmp_path / 'db.sqlite3'}", str(flag), pids))
    api.start()
    worker = pids.get(timeout=60)
    try:
        deadline = time.monotonic() + 60
        while not flag.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert flag.exists(), "the worker never began its pass"
        assert _running(worker)
        os.kill(int(api.pid or 0), signal.SIGKILL)
        api.join(10)
        deadline = time.monotonic() + 15
        while _running(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _running(worker), "the board worker kept computing after its API process was killed"
    finally:
        if _running(worker):
            os.kill(worker, signal.SIGKILL)
