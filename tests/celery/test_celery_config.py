"""The Celery app's guarantees as configuration, hostile messages, and the lease sweep against real services."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

import pytest
from sqlalchemy import select
from typer.testing import CliRunner

from robobpp.db import work
from robobpp.db.models import EpisodeRow, utcnow
from robobpp.worker.celery_app import (
    TASK_NAME,
    BrokerURLError,
    celery_config,
    check_broker_url,
    make_celery,
    task_id,
)
from robobpp.worker.celery_executor import requeue_expired
from robobpp.worker.options import WorkerOptions
from robobpp.worker.tasks import parse_episode_id
from tests.celery.conftest import cancel_active_submissions, new_submission


def test_config_acks_late_prefetch_one_json_only_and_a_long_visibility_timeout() -> None:
    conf = celery_config("redis://127.0.0.1:6379/0", queue="q", episode_timeout_s=1800, lease_s=120)
    assert conf["task_acks_late"] and conf["task_reject_on_worker_lost"]
    assert conf["worker_prefetch_multiplier"] == 1
    assert conf["task_serializer"] == "json" and conf["accept_content"] == ["json"]
    assert conf["result_backend"] is None and conf["task_ignore_result"]
    assert conf["broker_transport_options"]["visibility_timeout"] > 2 * 1800
    assert conf["task_time_limit"] > 1800  # the episode's own budget ends it first


def test_task_id_is_the_episode_id() -> None:
    assert task_id(42) == task_id("42") == "episode-42"


@pytest.mark.parametrize("url", ["", "http://x", "sqlite:///x.db", "postgresql://u:p@h/db", "redis-ish"])
def test_unsupported_brokers_are_refused(url: str) -> None:
    with pytest.raises(BrokerURLError):
        check_broker_url(url)


def test_refusal_never_echoes_the_broker_password() -> None:
    with pytest.raises(BrokerURLError) as info:
        check_broker_url("kafka://user:hunter2hunter2@broker:9092")
    assert "hunter2" not in str(info.value)


@pytest.mark.parametrize("url", ["redis://h:6379/0", "rediss://:pw@h/1", "amqp://guest:guest@h:5672//"])
def test_redis_and_rabbitmq_urls_are_accepted(url: str) -> None:
    assert check_broker_url(url) == url


@pytest.mark.parametrize("bad", ["1; DROP TABLE episodes", "-1", 0, True, 1.5, [1], None, "9" * 20, ""])
def test_hostile_message_payloads_are_rejected(bad: Any) -> None:
    with pytest.raises(ValueError):
        parse_episode_id(bad)


def test_the_task_refuses_a_hostile_payload_before_touching_the_database() -> None:
    app = make_celery(
        "redis://127.0.0.1:6379/0", WorkerOptions(database_url="postgresql+psycopg://nobody@0/x")
    )
    with pytest.raises(ValueError, match="positive integer"):
        app.tasks[TASK_NAME].run("../../etc/passwd")


def test_worker_command_without_a_broker_fails_clearly(monkeypatch: pytest.MonkeyPatch) -> None:
    from robobpp.cli import app, register_commands

    monkeypatch.delenv("ROBOBPP_BROKER_URL", raising=False)
    monkeypatch.setenv("ROBOBPP_DATABASE_URL", "postgresql+psycopg://postgres@127.0.0.1/test")
    register_commands()
    result = CliRunner().invoke(app, ["worker", "--concurrency", "1"])
    assert result.exit_code == 2
    assert "ROBOBPP_BROKER_URL" in result.output


def test_worker_command_refuses_a_non_broker_url(monkeypatch: pytest.MonkeyPatch) -> None:
    from robobpp.cli import app, register_commands

    monkeypatch.setenv("ROBOBPP_BROKER_URL", "http://127.0.0.1:9/")
    monkeypatch.setenv("ROBOBPP_DATABASE_URL", "postgresql+psycopg://postgres@127.0.0.1/test")
    register_commands()
    result = CliRunner().invoke(app, ["worker"])
    assert result.exit_code == 2
    assert "redis://" in result.output


@pytest.mark.postgres
@pytest.mark.redis
@pytest.mark.parametrize("broker", ["redis"], indirect=True)
def test_an_expired_lease_is_resent_exactly_once(pg_url: str, broker: tuple[str, str], factory: Any) -> None:
    """Two sweeps racing over one dead worker's episode: one message, one state change."""
    from kombu.connection import Connection

    url, queue = broker
    app = make_celery(url, WorkerOptions(database_url=pg_url, max_attempts=3), queue=queue)
    sub = new_submission(factory, policy="dbl", datasets=["repetitive"], groups=1, name=f"sweep-{queue}")
    past = utcnow() - timedelta(minutes=10)
    with factory() as s:
        episode_id = s.execute(select(EpisodeRow.id).where(EpisodeRow.submission_id == sub)).scalar_one()
    with factory() as s, s.begin():
        claim = work.claim_episode(
            s, "celery:dead:1", lease_s=1, max_attempts=3, now=past, episode_id=episode_id
        )
        assert claim is not None
    with factory() as s, s.begin():
        assert requeue_expired(s, app, 3) == [claim.episode_id]
    with factory() as s, s.begin():
        assert requeue_expired(s, app, 3) == []
    with factory() as s:
        row = s.execute(select(EpisodeRow).where(EpisodeRow.submission_id == sub)).scalar_one()
    assert (row.status, row.lease_token, row.attempts) == ("pending", None, 1)
    with Connection(url) as conn:
        assert conn.default_channel.client.llen(queue) == 1
    # The dead worker's late completion is refused: its token is gone.
    with factory() as s, s.begin():
        late = {
            "termination": "completed",
            "boxes_total": 1,
            "boxes_placed": 1,
            "metrics": {},
            "counters": {},
        }
        assert not work.complete_episode(s, claim.episode_id, claim.token, late, keep_trace=False)


@pytest.mark.postgres
@pytest.mark.redis
@pytest.mark.parametrize("broker", ["redis"], indirect=True)
def test_the_last_allowed_attempt_is_recorded_failed_not_resent(
    pg_url: str, broker: tuple[str, str], factory: Any
) -> None:
    url, queue = broker
    app = make_celery(url, WorkerOptions(database_url=pg_url, max_attempts=1), queue=queue)
    cancel_active_submissions(factory)
    sub = new_submission(factory, policy="dbl", datasets=["repetitive"], groups=1, name=f"last-{queue}")
    with factory() as s:
        episode_id = s.execute(select(EpisodeRow.id).where(EpisodeRow.submission_id == sub)).scalar_one()
    with factory() as s, s.begin():
        assert work.claim_episode(
            s,
            "celery:dead:2",
            lease_s=1,
            max_attempts=1,
            episode_id=episode_id,
            now=utcnow() - timedelta(hours=1),
        )
    with factory() as s, s.begin():
        assert requeue_expired(s, app, 1) == []
    with factory() as s:
        row = s.execute(select(EpisodeRow).where(EpisodeRow.submission_id == sub)).scalar_one()
    assert (row.status, row.termination) == ("failed", work.WORKER_LOST)


def test_each_app_runs_its_episodes_with_its_own_options() -> None:
    """Two apps in one process (the tests, an embedded worker beside a second deployment): each app's task is
    its own. Celery's default shared tasks gave the second app the first app's task, hence its options."""
    first = make_celery("redis://127.0.0.1:6379/0", WorkerOptions(database_url="sqlite:///first.db"))
    second = make_celery("redis://127.0.0.1:6379/0", WorkerOptions(database_url="sqlite:///second.db"))
    seen = []
    for app in (first, second):
        task = app.tasks[TASK_NAME]
        assert task.app is app
        # the closure's app is the one whose options the episode runs with
        (cell,) = [c.cell_contents for c in task.run.__closure__ if hasattr(c.cell_contents, "conf")]
        seen.append(cell.conf.robobpp_options.database_url)
    assert seen == ["sqlite:///first.db", "sqlite:///second.db"]
