"""A broker outage writes one line when it starts and one when it ends, not a traceback per round.

The dispatcher talks to the machine's real Redis through a TCP relay this test can switch off (listener
closed, open connections cut: what a Redis restart looks like to a client) and on again.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import pytest

from robobpp.db import work
from robobpp.db.migrate import upgrade
from robobpp.db.models import Participant
from robobpp.db.session import make_engine, make_session_factory
from robobpp.worker.celery_app import make_celery
from robobpp.worker.celery_executor import CeleryExecutor
from robobpp.worker.options import WorkerOptions
from robobpp.worker.outage import OutageLog
from tests.celery.conftest import _drop_queue, _reachable
from tests.celery.relay import Relay

pytestmark = pytest.mark.redis


def test_broker_outage_logs_one_line_down_and_one_up(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    if not _reachable("127.0.0.1", 6379):
        pytest.skip("Redis is not running at 127.0.0.1:6379")
    url = f"sqlite:///{tmp_path / 'outage.sqlite3'}"
    upgrade(url)
    factory = make_session_factory(make_engine(url))
    relay = Relay(("127.0.0.1", 6379))
    relay.up()
    queue = f"robobpp-outage-{relay.port}"
    app = make_celery(
        f"redis://127.0.0.1:{relay.port}/0", WorkerOptions(database_url=url, poll_interval_s=0.1), queue=queue
    )
    executor = CeleryExecutor(app, ping_every_s=10_000)
    caplog.set_level(logging.DEBUG, logger="robobpp.worker.celery")

    def submit(name: str) -> None:
        with factory() as s, s.begin():
            p = Participant(name=name)
            s.add(p)
            s.flush()
            work.create_submission(
                s, p, name=name, policy_url="builtin:dbl", datasets=["diverse"], settings=["math"], groups=2
            )

    try:
        executor.start()
        relay.down()
        # Work keeps arriving during the outage: every round tries the broker and fails. The outage lasts until
        # several failed rounds were seen (at most 20 s), not a fixed time: a slow machine gets as many rounds.
        deadline = time.monotonic() + 20
        i = 0
        while time.monotonic() < deadline and _still_unreachable(caplog) < 3:
            submit(f"during-{i}")
            i += 1
            time.sleep(0.4)
        relay.up()
        submit("after")
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and "reachable again" not in caplog.text:
            time.sleep(0.2)
    finally:
        executor.stop()
        relay.close()
        _drop_queue("redis://127.0.0.1:6379/0", queue)
    records = [
        r for r in caplog.records if r.name == "robobpp.worker.celery" and r.levelno >= logging.WARNING
    ]
    assert _still_unreachable(caplog) >= 3, (
        "the outage should have spanned several failed rounds:\n"
        + "\n".join(r.getMessage() for r in caplog.records)
    )
    # the broker's lines only: on a loaded machine the test's own writers can also keep SQLite locked past the
    # dispatcher's busy timeout, which it reports (once down, once up) as the database's own outage
    outage = [
        r.getMessage()
        for r in records
        if r.getMessage().startswith("robobpp-dispatcher: broker")
        and ("unreachable" in r.getMessage() or "reachable again" in r.getMessage())
    ]
    assert len(outage) == 2, outage
    assert "broker unreachable" in outage[0] and "broker reachable again" in outage[1]
    assert not any(r.exc_info for r in records), "no traceback for an outage"


def _still_unreachable(caplog: pytest.LogCaptureFixture) -> int:
    return sum("still unreachable" in r.getMessage() for r in caplog.records)


def test_a_bug_still_gets_its_traceback(caplog: pytest.LogCaptureFixture) -> None:
    log = logging.getLogger("robobpp.test.outage")
    caplog.set_level(logging.DEBUG, logger="robobpp.test.outage")
    outages = OutageLog(log, "loop")
    for _ in range(2):
        try:
            empty: dict[str, int] = {}
            empty["missing"]
        except KeyError as exc:
            outages.failed(exc)
    assert [bool(r.exc_info) for r in caplog.records] == [True, True]
