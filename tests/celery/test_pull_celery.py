"""Pull mode when the workers are Celery processes apart from the server: they reach the participant's
client through the server's relay (``ROBOBPP_PULL_RELAY_URL``), never the participant directly."""

from __future__ import annotations

import threading

import pytest

from robobpp.client.connect import connect
from robobpp.policies.dbl import DBL
from tests.celery.conftest import Fleet
from tests.server.conftest import ADMIN_TOKEN, ServerProcess, new_participant


@pytest.mark.parametrize("broker", ["redis"], indirect=True)
def test_celery_workers_drive_a_pull_client_through_the_server(fleet: Fleet, tmp_path) -> None:
    env = {
        **fleet.env,
        "ROBOBPP_ADMIN_TOKEN": ADMIN_TOKEN,
        "ROBOBPP_SETTINGS": '["math"]',
        "ROBOBPP_EVALUATE_BASELINES": "0",
        "ROBOBPP_GROUPS": "2",
        "ROBOBPP_WORKERS": "0",
    }
    server = ServerProcess(env, tmp_path).start()  # dispatches to Celery: no local worker pool
    try:
        fleet.env["ROBOBPP_PULL_RELAY_URL"] = server.url  # what a worker on another machine is told
        fleet.env["ROBOBPP_GROUPS"] = "2"
        fleet.start(2)
        token = new_participant(server.client(), "remote-lab")
        events: list[str] = []
        result = {}

        def run() -> None:
            result["sub"] = connect(
                DBL,
                server.url,
                token,
                name="via-celery",
                datasets=["diverse"],
                settings=["math"],
                parallel=2,
                on_event=events.append,
                poll_s=0.3,
            )

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        thread.join(timeout=150)
        assert not thread.is_alive(), f"{events}\n{fleet.logs()}"
        sub = result["sub"]
        assert (sub.mode, sub.status) == ("pull", "completed"), f"{events}\n{fleet.logs()}"
        episodes = server.client(token).get(f"/submissions/{sub.id}/episodes").json()
        assert len(episodes) == 2
        assert all(e["status"] == "done" and e["termination"] == "completed" for e in episodes), episodes
        workers = {row["worker"] for row in _workers(fleet.env["ROBOBPP_DATABASE_URL"], sub.id)}
        assert workers and all(w.startswith("celery:") for w in workers), workers
    finally:
        server.stop()


def _workers(url: str, submission_id: int) -> list[dict[str, str]]:
    from tests.server.conftest import db_rows

    return [
        dict(r._mapping)
        for r in db_rows(url, "SELECT worker FROM episodes WHERE submission_id = :s", s=submission_id)
    ]
