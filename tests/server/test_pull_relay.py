"""The pull relay against hostile clients: the worker ends the episode with the same reasons as in push mode
(a NaN, an answer over the cap, silence), and the relay refuses a worker without the episode's lease.

Every case runs three times: with one API app (the in-process bus), and across two apps on one database whose
buses meet through the real Redis, then the real RabbitMQ, the client on one and the worker on the other, so
each frame, and the oversize answer, crosses the broker."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.sync.client import connect as ws_connect

from robobpp.client import frames, wire
from robobpp.client.remote import RemotePolicy
from robobpp.client.serve import BackgroundServer
from robobpp.db import work
from robobpp.db.migrate import upgrade
from robobpp.db.session import make_engine, make_session_factory
from robobpp.episode import run_episode
from robobpp.server.app import create_app
from robobpp.server.config import Settings
from robobpp.worker.pull import PullTransport
from tests.conftest import make_spec
from tests.server.conftest import AMQP_URL, REDIS_URL, rabbitmq_or_skip, redis_or_skip

ADMIN = "relay-admin-token-0123456789abcdef"
Answer = Callable[[frames.Frame], bytes]


@pytest.fixture(
    scope="module",
    params=[
        "in-process",
        pytest.param("across-redis", marks=pytest.mark.redis),
        pytest.param("across-rabbitmq", marks=pytest.mark.rabbitmq),
    ],
)
def relay(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[dict[str, Any]]:
    tmp = tmp_path_factory.mktemp("relay")
    db = f"sqlite:///{tmp / 'relay.sqlite3'}"
    upgrade(db)
    across = request.param != "in-process"
    broker = {"across-redis": REDIS_URL, "across-rabbitmq": AMQP_URL}.get(request.param, "")
    settings = Settings(
        database_url=db,
        admin_token=ADMIN,
        state_dir=tmp,
        workers=0,
        groups=1,
        settings=("math",),
        evaluate_baselines=False,
        pull_broker_url=broker,
    )
    if request.param == "across-redis":
        redis_or_skip()
    elif request.param == "across-rabbitmq":
        rabbitmq_or_skip()
    with (
        BackgroundServer(create_app(settings, start_workers=False)) as server,
        BackgroundServer(create_app(settings, start_workers=False)) as other,
    ):
        worker_url = other.url if across else server.url
        admin = httpx.Client(base_url=server.url + "/api/v1", headers={"Authorization": f"Bearer {ADMIN}"})
        token = admin.post("/participants", json={"name": "hostile"}).json()["token"]
        mine = httpx.Client(base_url=server.url + "/api/v1", headers={"Authorization": f"Bearer {token}"})
        made = mine.post("/submissions", json={"name": "hostile", "mode": "pull", "datasets": ["diverse"]})
        assert made.status_code == 201, made.text
        assert made.json()["mode"] == "pull" and made.json()["policy_url"] == "pull:"
        factory = make_session_factory(make_engine(db))
        with factory() as session, session.begin():
            claim = work.claim_episode(session, "test:worker", lease_s=600, max_attempts=3)
        assert claim is not None and claim.mode == "pull"
        yield {
            "url": server.url,  # the participant's client connects here
            "worker_url": worker_url,  # the worker's episode socket lands here
            "token": token,
            "claim": claim,
            "submission": made.json()["id"],
        }


class ScriptedClient:
    """A pull client that answers every request with ``answer`` (or not at all, for ``None``)."""

    def __init__(self, relay: dict[str, Any], answer: Answer | None) -> None:
        url = relay["url"].replace("http", "ws") + f"/api/v1/pull/connect?submission={relay['submission']}"
        self.ws = ws_connect(url, additional_headers={"Authorization": f"Bearer {relay['token']}"})
        assert json.loads(self.ws.recv(timeout=5))["type"] == "welcome"
        self.answer = answer
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            while True:
                message = self.ws.recv()
                assert isinstance(message, bytes)  # a relay request is a binary frame
                request = frames.decode(message)
                if self.answer is not None:
                    self.ws.send(self.answer(request))
        except Exception:  # noqa: BLE001 - closed by the test
            return

    def close(self) -> None:
        self.ws.close()
        self.thread.join(timeout=5)


def _reply(request: frames.Frame, body: bytes, status: int = 200) -> bytes:
    return frames.encode({"id": request.id, "status": status}, [("content-type", "application/json")], body)


def _episode(relay: dict[str, Any], answer: Answer | None, lease: str | None = None) -> Any:
    client = ScriptedClient(relay, answer)
    try:
        claim = relay["claim"]
        transport = PullTransport(
            relay["worker_url"], claim.episode_id, lease or claim.token, wait_s=5, reconnect_s=1
        )
        policy = RemotePolicy(relay["url"], step_timeout_s=1.0, check_info=False, transport=transport)
        transport.headers_for = policy.request_headers
        return run_episode(make_spec([(10, 10, 5)] * 3, container=(20, 20, 20)), policy, "math")
    finally:
        client.close()


def _acting(body: bytes) -> Answer:
    return lambda r: _reply(r, b"{}" if r.envelope["path"].endswith(("/reset", "/echo", "/close")) else body)


def test_a_nan_answer_is_a_protocol_violation(relay: dict[str, Any]) -> None:
    result = _episode(relay, _acting(b'{"x": NaN, "y": 0, "orientation": 0}'))
    assert result.termination == "protocol_violation"
    assert "bad answer to POST /act (step 0)" in result.termination_detail


def test_an_answer_over_the_cap_is_a_protocol_violation(relay: dict[str, Any]) -> None:
    result = _episode(relay, _acting(b'{"x": 0, "y": 0, "orientation": 0, "pad": "' + b"x" * 80_000 + b'"}'))
    assert result.termination == "protocol_violation"
    assert "cap" in result.termination_detail


def test_a_silent_client_times_out_like_a_silent_server(relay: dict[str, Any]) -> None:
    result = _episode(relay, lambda r: _reply(r, b"{}") if r.envelope["path"].endswith("/reset") else b"junk")
    assert result.termination == "policy_error"  # a frame that is not one: the connection is garbage
    result = _episode(relay, None)
    assert result.termination == "policy_timeout"
    assert "within 1 s" in result.termination_detail


def test_the_relay_refuses_a_worker_without_the_lease(relay: dict[str, Any]) -> None:
    claim = relay["claim"]
    transport = PullTransport(relay["worker_url"], claim.episode_id, "not-the-lease", wait_s=2)
    with pytest.raises(wire.ConnectFailed, match="refused"):
        transport.pair(2)


def test_a_participant_cannot_join_another_ones_submission(relay: dict[str, Any]) -> None:
    from websockets.exceptions import ConnectionClosed

    url = relay["url"].replace("http", "ws") + f"/api/v1/pull/connect?submission={relay['submission']}"
    with (
        ws_connect(url, additional_headers={"Authorization": "Bearer rbp_wrong"}) as ws,
        pytest.raises(ConnectionClosed) as closed,
    ):
        ws.recv(timeout=5)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 4003
    assert "Unauthorized" in closed.value.rcvd.reason


def test_the_submission_records_its_mode(relay: dict[str, Any], tmp_path: Path) -> None:
    mine = httpx.Client(
        base_url=relay["url"] + "/api/v1", headers={"Authorization": f"Bearer {relay['token']}"}
    )
    bad = mine.post("/submissions", json={"name": "x", "mode": "pull", "policy_url": "http://example.org"})
    assert bad.status_code == 422 and "no policy_url" in bad.text
    missing = mine.post("/submissions", json={"name": "x"})
    assert missing.status_code == 422 and "policy_url is required in push mode" in missing.text
    assert mine.get(f"/submissions/{relay['submission']}").json()["mode"] == "pull"
