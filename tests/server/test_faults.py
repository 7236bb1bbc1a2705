"""Faults: a worker killed mid-episode, the whole server killed mid-evaluation, a cancelled submission.
SQL is the record of truth: every episode ends recorded exactly once."""

from __future__ import annotations

import os
import signal
import time

import pytest

from tests.server.conftest import SlowDBL, db_rows, new_participant, wait_for
from tests.server.test_e2e import GROUPS, local_figures


def _submit(client, policy, datasets):
    r = client.post(
        "/submissions",
        json={
            "name": "slow",
            "policy_url": policy.url,
            "secret": "policy-secret-123",
            "datasets": datasets,
            "settings": ["math"],
        },
    )
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _running(db_url: str, sid: int, min_step: int = 1) -> list:
    return db_rows(
        db_url,
        "SELECT id, worker, step FROM episodes WHERE submission_id = :s AND status = 'running' "
        "AND step >= :m",
        s=sid,
        m=min_step,
    )


def _check_recorded_once(client, db_url: str, sid: int, datasets: list[str]) -> None:
    sub = wait_for(
        lambda: (s := client.get(f"/submissions/{sid}").json())["status"] == "completed" and s, timeout_s=180
    )
    assert sub["progress"]["episodes_done"] == GROUPS * len(datasets)
    for run in sub["runs"]:
        assert run["extras"]["episodes"] == GROUPS
        expected = local_figures(run["dataset"], "math", "test")
        assert run["metrics"]["space_utilization"] == pytest.approx(expected["space_utilization"])
    rows = db_rows(db_url, "SELECT status, lease_token FROM episodes WHERE submission_id = :s", s=sid)
    assert all(status == "done" and token is None for status, token in rows)


def test_killed_worker_episode_is_retried_and_recorded_once(db_url, make_server, policy_server) -> None:
    server = make_server(db_url, ROBOBPP_EVALUATE_BASELINES="0")
    policy = policy_server(SlowDBL)
    client = server.client(new_participant(server.client()))
    sid = _submit(client, policy, ["diverse"])
    victim_id, worker, _step = wait_for(lambda: (r := _running(db_url, sid, 2)) and r[0])
    pid = int(worker.rsplit(":", 1)[1])
    os.kill(pid, signal.SIGKILL)
    _check_recorded_once(client, db_url, sid, ["diverse"])
    (attempts,) = db_rows(db_url, "SELECT attempts FROM episodes WHERE id = :i", i=victim_id)[0]
    assert attempts == 2


def test_server_crash_mid_evaluation_then_restart_completes(make_server, policy_server, tmp_path) -> None:
    db_url = f"sqlite:///{tmp_path / 'crash.sqlite3'}"
    server = make_server(db_url, ROBOBPP_EVALUATE_BASELINES="0")
    policy = policy_server(SlowDBL)
    token = new_participant(server.client())
    sid = _submit(server.client(token), policy, ["diverse", "longboard"])
    wait_for(lambda: _running(db_url, sid, 1))
    server.crash()  # server and its workers die mid-episode
    interrupted = db_rows(
        db_url, "SELECT id FROM episodes WHERE submission_id = :s AND status = 'running'", s=sid
    )
    assert interrupted
    server.start()
    _check_recorded_once(server.client(token), db_url, sid, ["diverse", "longboard"])


def test_cancel_stops_workers_taking_its_episodes(make_server, policy_server, tmp_path) -> None:
    db_url = f"sqlite:///{tmp_path / 'cancel.sqlite3'}"
    server = make_server(db_url, ROBOBPP_EVALUATE_BASELINES="0", ROBOBPP_WORKERS="1")
    policy = policy_server(SlowDBL)
    client = server.client(new_participant(server.client()))
    sid = _submit(client, policy, ["repetitive", "diverse"])
    wait_for(lambda: _running(db_url, sid, 1))
    r = client.post(f"/submissions/{sid}/cancel")
    assert r.status_code == 200 and r.json()["status"] == "cancelled"
    taken = db_rows(db_url, "SELECT attempts FROM episodes WHERE submission_id = :s ORDER BY id", s=sid)
    assert taken[0][0] == 1  # the worker keeps several in flight: how many it had taken does not matter
    time.sleep(4)  # longer than a lease renewal: the running episodes have noticed
    rows = db_rows(
        db_url,
        "SELECT status, attempts, metrics FROM episodes WHERE submission_id = :s ORDER BY id",
        s=sid,
    )
    assert [s for s, _a, _m in rows] == ["cancelled"] * 4
    assert [(a,) for _s, a, _m in rows] == taken  # nobody took another of its episodes
    assert all(m is None for _s, _a, m in rows)  # the in-flight episodes' results were dropped
    assert client.post(f"/submissions/{sid}/cancel").status_code == 409
    # the worker is free again: a new submission is evaluated
    sid2 = _submit(client, policy_server(), ["diverse"])
    wait_for(lambda: client.get(f"/submissions/{sid2}").json()["status"] == "completed", timeout_s=120)


def test_sigterm_to_the_whole_process_group_shuts_down_cleanly(make_server, policy_server, tmp_path) -> None:
    """``timeout`` and systemd signal every process of the group: workers and server must all exit."""
    db_url = f"sqlite:///{tmp_path / 'term.sqlite3'}"
    server = make_server(db_url, ROBOBPP_EVALUATE_BASELINES="0")
    policy = policy_server(SlowDBL)
    sid = _submit(server.client(new_participant(server.client())), policy, ["diverse"])
    wait_for(lambda: _running(db_url, sid, 1))
    os.killpg(server.proc.pid, signal.SIGTERM)
    server.proc.wait(40)  # uvicorn re-raises SIGTERM after its graceful shutdown: the code is -15
    assert "Application shutdown complete" in server.log.read_text()
