"""The paper protocol on the server: every submission with Math Pack episodes gets its physical settings again
as the paper made them — the Math actions and decision times replayed open loop — stored as runs and episodes
of protocol ``paper`` beside the closed-loop ones, under the same leases (docs/server.md, "The paper protocol")."""

from __future__ import annotations

from datetime import timedelta

import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import select

from robobpp.db import work
from robobpp.db.migrate import alembic_config, upgrade
from robobpp.db.models import Base, EpisodeRow, Participant, RunRow, Submission, utcnow
from robobpp.db.session import make_engine, make_session_factory, transaction
from robobpp.replay import paper_settings
from robobpp.worker.options import WorkerOptions
from robobpp.worker.run import claim_and_run
from tests.server.conftest import OFFLINE


@pytest.fixture
def factory(db_url: str):
    engine = make_engine(db_url)
    upgrade(db_url, engine=engine)
    yield make_session_factory(engine)
    engine.dispose()


def _submit(
    factory, settings=("math", "physics"), groups: int = 2, track: str = "public", datasets=("diverse",)
) -> int:
    with transaction(factory) as s:
        p = s.execute(select(Participant).where(Participant.name == "p")).scalar_one_or_none()
        if p is None:
            p = Participant(name="p", is_builtin=True)
            s.add(p)
            s.flush()
        return work.create_submission(
            s,
            p,
            name="dbl",
            policy_url="builtin:dbl",
            datasets=list(datasets),
            settings=list(settings),
            groups=groups,
            track=track,
        ).id


def _episodes(factory, sid: int) -> list[EpisodeRow]:
    with factory() as s:
        rows = s.execute(select(EpisodeRow).where(EpisodeRow.submission_id == sid).order_by(EpisodeRow.id))
        return list(rows.scalars())


def _drain(factory, db_url: str) -> int:
    options = WorkerOptions(database_url=db_url, spec_provider=OFFLINE, groups=2, lease_s=30)
    n = 0
    while claim_and_run(factory, options, "local:test:1") is not None:
        n += 1
    return n


def test_runs_and_waiting_replays_are_created_with_the_submission(factory) -> None:
    sid = _submit(factory, settings=("math", "physics", "execution"), groups=2)
    with factory() as s:
        runs = {(r.setting, r.protocol): r.status for r in s.execute(select(RunRow)).scalars()}
        sub = s.get(Submission, sid)
        assert sub is not None and sub.episodes_total == 2 * 5
    assert runs == {
        ("math", "closed"): "pending",
        ("physics", "closed"): "pending",
        ("execution", "closed"): "pending",
        ("physics", "paper"): "pending",
        ("execution", "paper"): "pending",
    }
    statuses = {(e.setting, e.protocol, e.group): e.status for e in _episodes(factory, sid)}
    assert statuses[("physics", "paper", 0)] == "waiting" and statuses[("math", "closed", 1)] == "pending"
    # no Math Pack, nothing to replay; a verification is compared on closed loop only
    assert paper_settings(["physics", "execution"], "private") == []
    assert paper_settings(["math", "physics"], "verify") == []
    assert paper_settings(["math", "execution"], "private") == ["execution"]


def test_waiting_replays_are_never_claimed_before_their_math_episode(factory) -> None:
    _submit(factory, settings=("math", "physics"), groups=1)
    with transaction(factory) as s:
        first = work.claim_episode(s, "w", lease_s=10, max_attempts=3)
        second = work.claim_episode(s, "w", lease_s=10, max_attempts=3)
        third = work.claim_episode(s, "w", lease_s=10, max_attempts=3)
    assert first is not None and (first.setting, first.protocol) == ("math", "closed")
    assert second is not None and (second.setting, second.protocol) == ("physics", "closed")
    assert third is None  # the replay waits for the Math episode


@pytest.mark.slow
@pytest.mark.parametrize("track", ["public", "private"])
def test_replays_play_exactly_the_math_actions(factory, db_url: str, track: str) -> None:
    sid = _submit(factory, settings=("math", "physics"), groups=2, track=track)
    assert _drain(factory, db_url) == 6  # 2 Math, 2 closed-loop Physics, 2 replays
    episodes = _episodes(factory, sid)
    assert all(e.status == "done" for e in episodes), [(e.setting, e.status, e.error) for e in episodes]
    with factory() as s:
        sub = s.get(Submission, sid)
        assert sub is not None and sub.status == "completed"
        runs = {(r.setting, r.protocol): r for r in s.execute(select(RunRow)).scalars()}
        assert runs[("physics", "paper")].status == "completed" and runs[("physics", "paper")].figures
        plans = s.execute(select(EpisodeRow.plan).where(EpisodeRow.protocol == "paper")).scalars().all()
        assert plans == [None, None]  # spent once the replay is recorded
    if track == "private":  # no trace kept: the replay read its plan, which is never served
        assert all(e.trace is None for e in episodes)
        return
    for group in (0, 1):
        math = next(e for e in episodes if (e.setting, e.group) == ("math", group))
        replay = next(e for e in episodes if (e.setting, e.protocol, e.group) == ("physics", "paper", group))
        closed = next(e for e in episodes if (e.setting, e.protocol, e.group) == ("physics", "closed", group))
        assert replay.physics_version is not None and replay.trace is not None and math.trace is not None
        played = [(s["action"], s["decision_time"]) for s in replay.trace["steps"]]
        planned = [(s["action"], s["decision_time"]) for s in math.trace["steps"]][: len(played)]
        assert played == planned and played  # the Math answers, in order, with their decision times
        assert replay.boxes_placed is not None and math.boxes_placed is not None and closed.trace is not None
        assert replay.boxes_placed <= math.boxes_placed
        assert replay.trace["steps"] != closed.trace["steps"] or replay.metrics == closed.metrics


def test_a_failed_math_episode_fails_its_replays(factory) -> None:
    sid = _submit(factory, settings=("math", "physics"), groups=1)
    now = utcnow()
    for attempt in range(2):  # the Math episode's worker dies twice: worker_lost
        with transaction(factory) as s:
            claim = work.claim_episode(
                s, "w", lease_s=10, max_attempts=2, now=now + timedelta(seconds=11 * attempt)
            )
            assert claim is not None and claim.setting == "math"
    with transaction(factory) as s:
        work.reap_expired(s, 2, now + timedelta(seconds=40))
    replay = next(e for e in _episodes(factory, sid) if e.protocol == "paper")
    assert (replay.status, replay.termination) == ("failed", work.WORKER_LOST)
    with factory() as s:
        run = s.get(RunRow, replay.run_id)
        assert run is not None and run.status == "failed"


def test_a_completed_math_episode_releases_its_replays_once(factory) -> None:
    sid = _submit(factory, settings=("math", "physics"), groups=1)
    with transaction(factory) as s:
        claim = work.claim_episode(s, "w", lease_s=10, max_attempts=3)
    assert claim is not None and claim.setting == "math"
    step = {
        "step": 0,
        "box": {"length": 1, "width": 1, "height": 1, "mass": 1},
        "action": None,
        "decision_time": 0.25,
        "termination": "no_feasible_placement",
    }
    result = {
        "termination": "no_feasible_placement",
        "termination_detail": "none",
        "boxes_total": 12,
        "boxes_placed": 0,
        "metrics": {"space_utilization": 0.0},
        "counters": {},
        "steps": [step],
    }
    for _ in range(2):  # a repeated completion (a duplicate message) changes nothing
        with transaction(factory) as s:
            work.complete_episode(s, claim.episode_id, claim.token, result, keep_trace=False)
    replay = next(e for e in _episodes(factory, sid) if e.protocol == "paper")
    assert replay.status == "pending"
    with factory() as s:
        plan = work.episode_plan(s, replay.id)
    assert plan is not None and plan["termination"] == "no_feasible_placement"
    assert [(p["action"], p["decision_time"]) for p in plan["steps"]] == [(None, 0.25)]


def test_cancel_cancels_waiting_replays(factory) -> None:
    sid = _submit(factory, settings=("math", "physics"), groups=1)
    with transaction(factory) as s:
        sub = s.get(Submission, sid)
        assert sub is not None and work.cancel_submission(s, sub)
    assert {e.status for e in _episodes(factory, sid)} == {"cancelled"}


def test_migration_round_trip_keeps_rows_closed(db_url: str) -> None:
    cfg = alembic_config(db_url)
    command.upgrade(cfg, "0006")
    engine = make_engine(db_url)
    try:
        with engine.begin() as conn:  # a row stored before the protocol existed
            conn.exec_driver_sql(
                "INSERT INTO participants (name, is_builtin, created_at) "
                "VALUES ('old', false, CURRENT_TIMESTAMP)"
            )
            conn.exec_driver_sql(
                "INSERT INTO submissions (participant_id, name, policy_url, track, mode, datasets, settings, "
                "lookahead, status, episodes_total, created_at) VALUES (1, 'old', 'builtin:dbl', 'private', "
                "'push', '[\"diverse\"]', '[\"physics\"]', 0, 'completed', 1, CURRENT_TIMESTAMP)"
            )
            conn.exec_driver_sql(
                "INSERT INTO runs (submission_id, dataset, setting, status, episodes_total) "
                "VALUES (1, 'diverse', 'physics', 'completed', 1)"
            )
        command.upgrade(cfg, "head")
        with engine.connect() as conn:
            assert conn.exec_driver_sql("SELECT protocol FROM runs").scalars().all() == ["closed"]
            # the models and the migrated schema agree (nothing for autogenerate to add or drop)
            diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
            assert diff == [], diff
        with (
            make_session_factory(engine)() as s,
            s.begin(),
        ):  # a paper run beside the closed one fits the keys
            s.add(
                RunRow(
                    submission_id=1, dataset="diverse", setting="physics", protocol="paper", status="pending"
                )
            )
        command.downgrade(cfg, "0006")
        with engine.connect() as conn:
            assert conn.exec_driver_sql("SELECT count(*) FROM runs").scalar_one() == 1
        command.upgrade(cfg, "head")
    finally:
        engine.dispose()


@pytest.fixture
def protocol_app(db_url: str, tmp_path):
    from fastapi.testclient import TestClient

    from robobpp.server.app import create_app
    from robobpp.server.bootstrap import bootstrap
    from robobpp.server.config import Settings

    settings = Settings(
        database_url=db_url,
        state_dir=tmp_path,
        admin_token="paper-admin-token-0123456789abcdef",
        workers=0,
        evaluate_baselines=False,
        settings=("math", "physics"),
        datasets=("diverse",),
        groups=2,
        board_refresh_s=0,
        spec_provider=OFFLINE,
    )
    app = create_app(settings, start_workers=False)
    bootstrap(app.state.runtime)
    with TestClient(app) as client:
        yield app, client
    app.state.runtime.dispose()


@pytest.mark.slow
def test_boards_grid_pages_and_api_serve_both_protocols(protocol_app, db_url: str) -> None:
    app, client = protocol_app
    factory = app.state.runtime.session_factory
    ids = []
    for name in ("dbl", "hm", "lsah"):
        with transaction(factory) as s:
            p = Participant(name=f"baseline-{name}", is_builtin=True)
            s.add(p)
            s.flush()
            ids.append(
                work.create_submission(
                    s,
                    p,
                    name=name,
                    policy_url=f"builtin:{name}",
                    datasets=["diverse"],
                    settings=["math", "physics"],
                    groups=2,
                ).id
            )
    admin = {"Authorization": "Bearer paper-admin-token-0123456789abcdef"}
    queue = client.get("/metrics", headers=admin).text  # the replays wait for their Math episodes
    assert (
        'robobpp_episodes{status="waiting"} 6.0' in queue
        and 'robobpp_episodes{status="pending"} 12.0' in queue
    )
    assert _drain(factory, db_url) == 3 * 6
    assert 'robobpp_episodes{status="waiting"} 0.0' in client.get("/metrics", headers=admin).text
    boards = {}
    for protocol in (None, "closed", "paper"):
        params = {"view": "all"} | ({"protocol": protocol} if protocol else {})
        board = client.get("/api/v1/leaderboards/diverse/physics", params=params).json()
        boards[protocol] = board
        assert board["protocol"] == (protocol or "closed")  # closed is the default: old URLs unchanged
        assert {e["submission_id"] for e in board["entries"]} == set(ids) and board["groups"] == 2
        for e in board["entries"]:
            assert e["score_low"] <= e["score"] + 1e-9 <= e["score_high"] + 2e-9
            lo, hi = e["intervals"]["space_utilization"]
            assert lo <= e["metrics"]["space_utilization"] <= hi
    assert boards[None] == boards["closed"]
    closed = {e["submission_id"]: e["metrics"] for e in boards["closed"]["entries"]}
    paper = {e["submission_id"]: e["metrics"] for e in boards["paper"]["entries"]}
    with factory() as s:  # each board shows its own protocol's runs
        for sid in ids:
            for protocol, on_board in (("closed", closed), ("paper", paper)):
                run = s.execute(
                    select(RunRow).where(
                        RunRow.submission_id == sid, RunRow.setting == "physics", RunRow.protocol == protocol
                    )
                ).scalar_one()
                assert run.metrics == on_board[sid]
    math = client.get("/api/v1/leaderboards/diverse/math", params={"protocol": "paper"}).json()
    assert math["protocol"] == "closed" and len(math["entries"]) == 3  # Math Pack: one board for both
    assert client.get("/api/v1/leaderboards/diverse/physics", params={"protocol": "open"}).status_code == 422
    grid = client.get("/api/v1/leaderboards", params={"protocol": "paper", "view": "all"}).json()
    assert grid["protocol"] == "paper" and len(grid["rows"]) == 3
    for row in grid["rows"]:
        cell = row["cells"]["physics/diverse"]
        entry = next(e for e in boards["paper"]["entries"] if e["submission_id"] == row["submission_id"])
        assert (cell["score"], cell["score_low"], cell["score_high"]) == (
            entry["score"],
            entry["score_low"],
            entry["score_high"],
        )
        assert row["mean_low"] - 1e-6 <= row["mean"] <= row["mean_high"] + 1e-6  # bounds to 6 decimals
    assert client.get("/api/v1/leaderboards").json()["protocol"] == "closed"
    runs = client.get(f"/api/v1/submissions/{ids[0]}", headers=admin).json()["runs"]
    assert sorted((r["setting"], r["protocol"]) for r in runs) == [
        ("math", "closed"),
        ("physics", "closed"),
        ("physics", "paper"),
    ]

    page = client.get("/boards/diverse/physics", params={"protocol": "paper"}).text
    assert "paper protocol (plan in Math, replay)" in page and "· paper protocol" in page
    assert 'href="?view=best">closed loop (the benchmark)' in page
    home = client.get("/", params={"protocol": "paper"}).text
    assert 'data-role="protocol-note"' in home and "/boards/diverse/physics?protocol=paper" in home
    assert 'data-role="protocol-note"' not in client.get("/").text
    sub_page = client.get(f"/submissions/{ids[0]}").text
    assert 'data-protocol="paper"' in sub_page and "/boards/diverse/physics?protocol=paper" in sub_page

    # the Reproduction: those baselines' Math runs and paper-protocol runs beside the paper's tables
    from robobpp.paper import paper_tables
    from robobpp.reproduction import spearman

    data = client.get("/api/v1/reproduction").json()
    assert data["track"] == "private" and data["protocol"] == "paper"
    assert sorted((r["setting"], r["protocol"], r["policy"]) for r in data["runs"]) == sorted(
        [("math", "closed", p) for p in ("dbl", "hm", "lsah")]
        + [("physics", "paper", p) for p in ("dbl", "hm", "lsah")]
    )
    cells = {(c["setting"], c["policy"], c["metric"]): c for c in data["cells"] if c["dataset"] == "diverse"}
    by_name = dict(zip(("dbl", "hm", "lsah"), ids, strict=True))
    for policy, sid in by_name.items():
        cell = cells[("physics", policy, "space_utilization")]
        assert cell["ours"] == paper[sid]["space_utilization"]  # the paper-protocol run, not the closed one
        published = paper_tables().get("physics", "diverse", policy, "space_utilization")
        assert published is not None and (cell["paper"], cell["table"]) == (published.value, published.table)
        assert cell["diff"] == pytest.approx(cell["ours"] - cell["paper"])
    (agreement,) = [
        a
        for a in data["agreement"]
        if (a["setting"], a["dataset"], a["metric"]) == ("physics", "diverse", "space_utilization")
    ]
    column = [cells[("physics", p, "space_utilization")] for p in ("dbl", "hm", "lsah")]
    assert agreement["spearman"] == spearman([c["ours"] for c in column], [c["paper"] for c in column])
    assert agreement["mean_abs_diff"] == pytest.approx(sum(abs(c["diff"]) for c in column) / 3)
    assert {m for s, _p, m in cells if s == "physics"} >= {"space_utilization", "static_stability"}
    page = client.get("/reproduction").text
    assert 'data-role="protocol-explained"' in page and 'href="/reproduction"' in page
    assert 'data-setting="physics" data-metric="space_utilization"' in page and "Spearman" in page
    assert page.index('data-metric="space_utilization"') < page.index(
        'data-metric="occupancy"'
    )  # utilisation first

    # the CLI: robobpp leaderboard --protocol paper, against the same server over HTTP
    import json

    from typer.testing import CliRunner

    from robobpp.cli import app as cli_app
    from robobpp.cli import register_commands
    from robobpp.client.serve import BackgroundServer

    register_commands()
    cli = CliRunner()
    with BackgroundServer(app) as served:
        printed = cli.invoke(
            cli_app,
            [
                "leaderboard",
                "--dataset",
                "diverse",
                "--setting",
                "physics",
                "--protocol",
                "paper",
                "--view",
                "all",
                "--server",
                served.url,
            ],
        )
        assert printed.exit_code == 0, printed.output
        assert "physics/diverse · paper protocol" in printed.stdout
        as_json = cli.invoke(
            cli_app,
            [
                "leaderboard",
                "--dataset",
                "diverse",
                "--setting",
                "physics",
                "--protocol",
                "paper",
                "--view",
                "all",
                "--json",
                "--server",
                served.url,
            ],
        )
        served_board = json.loads(as_json.stdout)
        assert served_board["protocol"] == "paper"
        assert {e["submission_id"]: e["metrics"] for e in served_board["entries"]} == paper
        exported = cli.invoke(
            cli_app,
            [
                "leaderboard",
                "--dataset",
                "diverse",
                "--setting",
                "physics",
                "--protocol",
                "paper",
                "--format",
                "md",
                "--server",
                served.url,
            ],
        )
        assert exported.exit_code == 0 and "physics/diverse · paper protocol" in exported.stdout
        grid_shown = cli.invoke(cli_app, ["leaderboard", "--protocol", "paper", "--server", served.url])
        assert grid_shown.exit_code == 0 and "Physics/Execution under the paper protocol" in grid_shown.stdout
        from robobpp.client.api import ServerClient

        with ServerClient(served.url, "paper-admin-token-0123456789abcdef") as api:
            standings = {s.board: s for s in api.standings(api.submission(ids[0]))}
        assert set(standings) == {"math/diverse", "physics/diverse", "physics/diverse (paper protocol)"}
        mine = standings["physics/diverse (paper protocol)"]  # stands on the paper-protocol board
        assert mine.protocol == "paper" and mine.metrics == paper[ids[0]] and mine.entries == 3
        assert mine.rank is not None and standings["physics/diverse"].metrics == closed[ids[0]]
        closed_shown = cli.invoke(
            cli_app, ["leaderboard", "--dataset", "diverse", "--setting", "physics", "--server", served.url]
        )
        assert closed_shown.exit_code == 0 and "paper protocol" not in closed_shown.stdout
    bad = cli.invoke(cli_app, ["leaderboard", "--protocol", "open"])
    assert bad.exit_code == 2 and "unknown protocol 'open'" in bad.output


def test_the_client_says_when_a_server_has_no_paper_protocol() -> None:
    """A server from before protocols ignores ``protocol=paper``: its closed-loop board is never taken for one."""
    from fastapi import FastAPI

    from robobpp.client.api import ServerClient, ServerError
    from robobpp.client.serve import BackgroundServer

    old = FastAPI()
    board = {
        "dataset": "diverse",
        "setting": "physics",
        "track": "private",
        "metrics": [],
        "weights": {},
        "ranked_by": "relative",
        "anchors": "a",
        "groups": 0,
        "resamples": 0,
        "confidence": 0.95,
        "view": "best",
        "total": 0,
        "limit": 50,
        "offset": 0,
        "entries": [],
        "unranked_total": 0,
        "unranked": [],
    }
    old.get("/api/v1/leaderboards/{dataset}/{setting}")(lambda dataset, setting: board)
    with BackgroundServer(old) as served, ServerClient(served.url) as client:
        assert client.leaderboard("diverse", "physics").protocol == "closed"
        with pytest.raises(ServerError, match="served the closed protocol, not paper"):
            client.leaderboard("diverse", "physics", protocol="paper")


@pytest.mark.slow
def test_a_replay_whose_worker_died_is_taken_over_and_recorded_once(factory, db_url: str) -> None:
    import time

    sid = _submit(factory, settings=("math", "physics"), groups=1)
    options = WorkerOptions(database_url=db_url, spec_provider=OFFLINE, groups=1, lease_s=30)
    assert claim_and_run(factory, options, "local:test:1")  # the Math episode, which releases its replay
    claims = []
    for _ in range(2):  # a worker takes both Physics episodes, then dies: its leases run out
        with transaction(factory) as s:
            claims.append(work.claim_episode(s, "local:dead:2", lease_s=0.05, max_attempts=3))
    (dead,) = [c for c in claims if c is not None and c.protocol == "paper"]
    time.sleep(0.2)
    assert _drain(factory, db_url) == 2  # the closed-loop Physics episode, and the replay taken over
    late = {
        "termination": "completed",
        "termination_detail": "",
        "boxes_total": 1,
        "boxes_placed": 1,
        "metrics": {"space_utilization": 1.0},
        "counters": {},
        "steps": [],
    }
    with transaction(factory) as s:  # the dead worker's result arrives late: nothing is written
        assert not work.complete_episode(s, dead.episode_id, dead.token, late, keep_trace=False)
    replay = next(e for e in _episodes(factory, sid) if e.protocol == "paper")
    assert (replay.status, replay.attempts, replay.worker) == ("done", 2, "local:test:1")
    assert replay.metrics is not None and replay.metrics["space_utilization"] != 1.0
    with factory() as s:
        run = s.get(RunRow, replay.run_id)
        assert run is not None and run.status == "completed" and run.extras["episodes"] == 1


#: Boxes of :func:`real_spec` (a real train group, cut short: the test stays a few seconds).
REAL_BOXES = 20


def real_spec(dataset: str, split: str, group: int, groups: int):
    """The real public train group (seed 0), its first :data:`REAL_BOXES` boxes (a spec provider)."""
    import dataclasses

    from robobpp.datasets import sampling

    spec = sampling.episode_specs(dataset, "train", groups=groups, seed=0)[group]
    return dataclasses.replace(spec, boxes=spec.boxes[:REAL_BOXES])


@pytest.mark.slow
def test_the_server_replay_equals_the_local_paper_protocol(tmp_path, real_data) -> None:
    """The workers' paper-protocol episode is the one ``robobpp evaluate --protocol paper`` plays locally."""
    from robobpp.policies import load_policy
    from robobpp.replay import run_paper_loop

    url = f"sqlite:///{tmp_path / 'real.sqlite3'}"
    engine = make_engine(url)
    upgrade(url, engine=engine)
    factory = make_session_factory(engine)
    sid = _submit(factory, settings=("math", "physics"), groups=1, datasets=("longboard",))
    options = WorkerOptions(database_url=url, spec_provider=f"{__name__}:real_spec", groups=1, lease_s=60)
    while claim_and_run(factory, options, "local:test:1") is not None:
        pass
    replay = next(e for e in _episodes(factory, sid) if e.protocol == "paper")
    local = run_paper_loop(real_spec("longboard", "train", 0, 1), load_policy("dbl"), ["physics"])["physics"]
    assert replay.status == "done" and local.protocol == "paper"
    assert (replay.termination, replay.boxes_placed, replay.physics_version) == (
        local.termination,
        local.boxes_placed,
        local.physics_version,
    )
    assert replay.metrics is not None
    for key in ("space_utilization", "occupancy", "local_stability", "static_stability"):
        assert replay.metrics[key] == local.metrics[key], key
    engine.dispose()
