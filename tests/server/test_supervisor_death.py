"""``robobpp serve`` killed outright (SIGKILL, as the OOM killer does) takes every process it
started with it: its API processes once lived on as orphans, answering ``/healthz`` "ok, workers: 2" and
accepting submissions that nothing dispatched, and a new ``robobpp serve`` failed with "Address already in use"
until someone killed them by hand. Now they, the local workers (one mid-episode) and the board worker end within
seconds, the port is free, and a restarted server finishes the submission accepted before the kill. With one API
process (``robobpp serve`` alone) the workers and the board worker go the same way.

An API process whose supervisor is gone answers ``/healthz`` 503 for as long as it lasts."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import time
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from robobpp.server.app import create_app
from robobpp.server.processes import SupervisorsWorkers
from robobpp.worker.lifeline import Lifeline
from tests.server.conftest import (
    REDIS_URL,
    ServerProcess,
    SlowDBL,
    db_rows,
    free_port,
    new_participant,
    redis_or_skip,
    server_env,
    wait_for,
)
from tests.server.test_api import make_settings
from tests.server.test_faults import _check_recorded_once, _running, _submit
from tests.server.test_pull import listening_ports


def _processes() -> dict[int, tuple[int, str]]:
    """Every process of the machine: pid → (parent pid, state letter), from /proc."""
    table = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            after_name = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            continue
        table[int(entry.name)] = (int(after_name[1]), after_name[0])
    return table


def _descendants(root: int) -> dict[int, str]:
    """Every process below ``root`` (children, theirs, …): pid → command line."""
    table = _processes()
    found: dict[int, str] = {}
    todo = [root]
    while todo:
        parent = todo.pop()
        for pid, (ppid, _state) in table.items():
            if ppid == parent and pid not in found:
                try:
                    found[pid] = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
                except FileNotFoundError:
                    found[pid] = "?"
                todo.append(pid)
    return found


def _alive(pid: int) -> bool:
    state = _processes().get(pid)
    return state is not None and state[1] != "Z"  # a zombie has ended (init reaps it)


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads the process tree from /proc")
@pytest.mark.parametrize("api_processes", [1, pytest.param(2, marks=pytest.mark.redis)])
def test_sigkill_of_the_supervisor_ends_every_process_it_started_and_a_restart_finishes_the_work(
    tmp_path: Path, policy_server, api_processes: int
) -> None:
    extra = {"ROBOBPP_EVALUATE_BASELINES": "0"}
    if api_processes > 1:
        redis_or_skip()
        extra["ROBOBPP_PULL_BROKER_URL"] = REDIS_URL
    db = f"sqlite:///{tmp_path / 'killed.sqlite3'}"
    port = free_port()
    args = ("--server-workers", str(api_processes))
    server = ServerProcess(server_env(tmp_path, db, **extra), tmp_path, args=args, port=port).start()
    tree: dict[int, str] = {}
    try:
        assert server.proc is not None
        policy = policy_server(SlowDBL)
        token = new_participant(server.client())
        sid = _submit(server.client(token), policy, ["diverse"])
        wait_for(lambda: _running(db, sid, 1))  # a worker is in the middle of an episode
        tree = _descendants(server.proc.pid)
        if api_processes > 1:
            assert len([pid for pid in tree if port in listening_ports(pid)]) == api_processes, tree
        # the API processes (with one, the supervisor is it), 2 local workers, the board worker, and
        # multiprocessing's resource tracker
        assert len(tree) == (api_processes if api_processes > 1 else 0) + 4, tree
        assert sum("resource_tracker" in cmd for cmd in tree.values()) == 1, tree

        os.kill(server.proc.pid, signal.SIGKILL)  # the supervisor alone, as the OOM killer picks one process
        server.proc.wait(10)
        deadline = time.monotonic() + 10
        while any(_alive(pid) for pid in tree) and time.monotonic() < deadline:
            time.sleep(0.1)
        survivors = {pid: cmd for pid, cmd in tree.items() if _alive(pid)}
        assert not survivors, f"outlived the supervisor by 10 s: {survivors}"

        with pytest.raises(httpx.TransportError):  # nobody answers on the port any more...
            httpx.get(server.url + "/healthz", timeout=2)
        with socket.socket() as probe:  # ...nor holds it: bound at once, as `robobpp serve` binds it
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind(("127.0.0.1", port))
        interrupted = db_rows(
            db, "SELECT id FROM episodes WHERE submission_id = :s AND status = 'running'", s=sid
        )
        assert interrupted  # still leased to the killed workers: the restart hands them back

        server.start()  # the same port
        _check_recorded_once(server.client(token), db, sid, ["diverse"])
    finally:
        server.stop(signal.SIGKILL)
        for pid in tree:  # whatever outlived the supervisor (the failure this test is about) goes too
            if _alive(pid):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)


def test_healthz_of_an_api_process_whose_supervisor_is_gone_is_not_ok(tmp_path: Path) -> None:
    """Between the supervisor's death and its own end an API process must not report "ok, workers: 2": it would
    accept submissions that nothing dispatches."""
    import multiprocessing

    settings = make_settings(f"sqlite:///{tmp_path / 'health.sqlite3'}", tmp_path, board_worker="off")
    app = create_app(settings, start_workers=False)
    count = multiprocessing.get_context("spawn").RawValue("i", 2)  # the supervisor's last count
    with TestClient(app) as client:
        app.state.runtime.executor = SupervisorsWorkers(count, Lifeline(os.getppid(), kernel=False))
        r = client.get("/healthz")
        assert r.status_code == 200 and r.json()["workers"] == 2
        gone = Lifeline(os.getpid(), kernel=False)  # a process is never its own parent: as after the death
        app.state.runtime.executor = SupervisorsWorkers(count, gone)
        r = client.get("/healthz")
        assert r.status_code == 503 and r.json() == {"status": "unavailable", "supervisor": "gone"}
        assert app.state.runtime.executor.alive() == 0
