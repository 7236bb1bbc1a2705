"""The operator's first hour (issue 38): the demo plays short episodes and says it is a demo; the log has a time
on every line, a line per finished submission and the backlog's expected end; Ctrl-C ends the server without a
traceback; ``connect`` prints progress lines off a terminal; a server whose stored baselines no longer fit its
settings (the demo's database served without --demo) says so and queues them again; the baselines a first start
queues never bury the operator's own submission."""

from __future__ import annotations

import logging
import os
import re
import signal
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from robobpp.db import waiting, work
from robobpp.db.models import EpisodeRow, Participant, Submission
from robobpp.server.app import create_app
from robobpp.server.bootstrap import BUILTIN_PARTICIPANT, bootstrap
from robobpp.server.config import Settings
from robobpp.worker.options import worker_options
from robobpp.worker.run import claim_and_run
from robobpp.worker.specs import episode_spec
from tests.server.conftest import OFFLINE, new_participant, wait_for

ADMIN = "first-hour-admin-token-0123456789"
#: A log line as ``robobpp.logs`` writes it: date, time, level, logger.
STAMPED = re.compile(r"^\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2} (DEBUG|INFO|WARNING|ERROR|CRITICAL) [\w.]+: ")
#: A line that is a log record without its time stamp (the old format, or uvicorn's own).
UNSTAMPED = re.compile(r"^(DEBUG|INFO|WARNING|ERROR|CRITICAL)[ :]")


def drain(app: Any) -> None:
    runtime = app.state.runtime
    while claim_and_run(runtime.session_factory, worker_options(runtime.settings), "test:host:1") is not None:
        pass


def test_the_demo_plays_few_groups_of_short_episodes_on_the_private_track(tmp_path: Path) -> None:
    from robobpp.cli.server import DEMO_BOXES, DEMO_GROUPS, demo_overrides

    demo = Settings(**demo_overrides(tmp_path))
    assert (
        demo.demo
        and demo.groups == DEMO_GROUPS
        and demo.max_boxes == DEMO_BOXES
        and not demo.public_baselines
    )
    assert "execution" not in demo.enabled_settings and "math" in demo.enabled_settings
    full = episode_spec("diverse", "test", 0, groups=1, private_dir=tmp_path, provider=OFFLINE)
    short = episode_spec("diverse", "test", 0, groups=1, private_dir=tmp_path, provider=OFFLINE, max_boxes=5)
    assert short.boxes == full.boxes[:5] and len(full.boxes) > 5


def test_demo_state_served_without_demo_says_so_and_queues_the_baselines_again(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    def configured(groups: int, max_boxes: int, demo: bool) -> Settings:
        return Settings(
            database_url=f"sqlite:///{tmp_path / 'state.sqlite3'}",
            state_dir=tmp_path,
            admin_token=ADMIN,
            workers=0,
            demo=demo,
            settings=("math",),
            datasets=("diverse",),
            groups=groups,
            max_boxes=max_boxes,
            baselines=("dbl", "random"),
            public_baselines=False,
            board_refresh_s=0,
            board_worker="thread",
            spec_provider=OFFLINE,
        )

    # the demo: 1 group of 5 boxes, labelled as a demo on its pages
    demo = create_app(configured(1, 5, True), start_workers=False)
    with TestClient(demo) as client:
        drain(demo)
        with demo.state.runtime.session() as s:
            assert set(s.execute(select(EpisodeRow.boxes_total)).scalars()) == {5}
        wait_for(lambda: "2 ranked" in client.get("/").text, timeout_s=30)
        home = client.get("/").text
        assert 'data-role="demo"' in home and "the first 5 boxes of each" in home
        assert 'data-role="requeued"' not in home
    demo.state.runtime.dispose()

    # the same state served with the real settings: the log and the pages say why, the baselines run again
    real = create_app(configured(2, 0, False), start_workers=False)
    with caplog.at_level(logging.WARNING, logger="robobpp.server"):
        bootstrap(real.state.runtime)
    said = caplog.text
    assert "2 baseline entries no longer fit this server's settings" in said
    assert "it ran 1 group(s) per board, the boards have 2" in said
    assert "its episodes played the first 5 of each group, the boards play every box" in said
    with TestClient(real) as client:
        with real.state.runtime.session() as s:
            queued = s.execute(select(Submission.policy_url).where(Submission.status == "queued")).scalars()
            assert sorted(queued) == ["builtin:dbl", "builtin:random"]
        for page in ("/", "/boards/diverse/math"):
            text = client.get(page).text
            assert 'data-role="requeued"' in text and "the boards have 2" in text, page
            assert 'data-role="backlog"' in text and "baselines 0 of 2 done" in text, page
            assert 'data-role="demo"' not in text
        drain(real)
        wait_for(lambda: "2 ranked" in client.get("/").text, timeout_s=30)
        home = client.get("/").text
        assert 'data-role="requeued"' not in home and 'data-role="backlog"' not in home
    with caplog.at_level(logging.WARNING, logger="robobpp.server"):
        caplog.clear()
        bootstrap(real.state.runtime)  # now current: nothing queued again
    assert "no longer fit" not in caplog.text and "queued" not in caplog.text
    real.state.runtime.dispose()


def test_the_operators_own_submission_goes_before_the_baselines(tmp_path: Path) -> None:
    """The operator submits with the admin token, as the built-in participant: its submission was claimed
    after every baseline episode a first start queued (position 8,817 on the docs' settings)."""
    settings = Settings(
        database_url=f"sqlite:///{tmp_path / 'order.sqlite3'}",
        state_dir=tmp_path,
        admin_token=ADMIN,
        workers=0,
        settings=("math",),
        datasets=("diverse", "longboard"),
        groups=3,
        baselines=("dbl", "hm", "random"),
        spec_provider=OFFLINE,
    )
    app = create_app(settings, start_workers=False)
    bootstrap(app.state.runtime)  # 6 baseline submissions, 36 episodes
    try:
        with app.state.runtime.session() as s:
            builtin = s.execute(
                select(Participant).where(Participant.name == BUILTIN_PARTICIPANT)
            ).scalar_one()
            mine = work.create_submission(
                s,
                builtin,
                name="operator check",
                policy_url="http://127.0.0.1:9/policy",
                datasets=["diverse"],
                settings=["math"],
                groups=3,
            )
            place = waiting.queue_place(s, mine)
            assert place is not None and place["position"] == 1 and place["ahead"] == 0
            baseline = (
                s.execute(select(Submission).where(Submission.policy_url == "builtin:hm")).scalars().first()
            )
            assert baseline is not None
            behind = waiting.queue_place(s, baseline)
            assert behind is not None and behind["ahead"] >= 3 + 6  # the operator's 3, DBL's 6 (older)
            claims = [work.claim_episode(s, f"w{i}", lease_s=60, max_attempts=3) for i in range(3)]
            assert [c.submission_id if c else None for c in claims] == [mine.id] * 3
            backlog = waiting.backlog(s, workers=2)
            assert backlog is not None and backlog.queued == 6 and backlog.running == 1
            assert backlog.episodes_left == 36 + 3 and backlog.episodes_running == 3
            assert backlog.baselines == {"queued": 6} and backlog.expected_s is None  # nothing finished yet
    finally:
        app.state.runtime.dispose()


def test_serve_logs_with_times_and_progress_and_ctrl_c_ends_it_without_a_traceback(
    make_server, tmp_path
) -> None:
    """Ctrl-C at a terminal signals the whole process group (the server, its board worker and workers): the
    board worker printed a KeyboardInterrupt traceback under the server's clean shutdown."""
    server = make_server(f"sqlite:///{tmp_path / 'serve.sqlite3'}", ROBOBPP_BOARD_WORKER="process")
    wait_for(lambda: "submission #1 DBL (baselines, private track) completed" in server.log.read_text())
    wait_for(lambda: "backlog: every submission has finished" in server.log.read_text())
    assert server.proc is not None
    os.killpg(server.proc.pid, signal.SIGINT)
    code = server.proc.wait(40)
    log = server.log.read_text()
    assert "Traceback" not in log and "KeyboardInterrupt" not in log, log[-3000:]
    assert code == 130, code  # docs/server.md: 128 + SIGINT, as a shell reports an interrupted command
    lines = log.splitlines()
    assert not [line for line in lines if UNSTAMPED.match(line)]
    assert any(STAMPED.match(line) and "uvicorn" in line for line in lines)  # uvicorn's own lines too
    started = next(line for line in lines if "queued 2 baseline submission(s)" in line)
    assert STAMPED.match(started) and "12 episodes" in started  # DBL: 2 tracks × 3 datasets × 2 groups
    assert any(STAMPED.match(line) and "backlog: " in line and "expected end" in line for line in lines)


def test_connect_prints_progress_lines_off_a_terminal(make_server, tmp_path, monkeypatch) -> None:
    from typer.testing import CliRunner

    from robobpp.cli import app, register_commands
    from robobpp.cli import progress as progress_module

    server = make_server(f"sqlite:///{tmp_path / 'connect.sqlite3'}", ROBOBPP_EVALUATE_BASELINES="0")
    token = new_participant(server.client(), "natted")
    monkeypatch.setattr(progress_module, "PROGRESS_LINE_S", 0.0)
    register_commands()
    result = CliRunner().invoke(
        app,
        ["connect", "dbl", "--dataset", "diverse", "--setting", "math"],
        env={"ROBOBPP_TOKEN": token, "ROBOBPP_SERVER": server.url},
    )
    assert result.exit_code == 0, result.output
    assert re.search(r"^#1 (queued|running)[^\n]*: \d/2 · \d+ s$", result.output, re.M), result.output
