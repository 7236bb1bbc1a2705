"""Provenance on the server (docs/benchmark.md, "Provenance"): each episode records what produced it, runs and
submissions serve it merged, boards never mix Math rules or sampler versions, and a board exports as CSV,
Markdown and LaTeX with each participant's number of entries beside its best one."""

from __future__ import annotations

import csv
import io
from datetime import UTC, datetime
from typing import Any

import pytest
from sqlalchemy import select
from typer.testing import CliRunner

import robobpp
from robobpp import provenance
from robobpp.boards.engine import leaderboard
from robobpp.datasets.sampling import SAMPLER_VERSION
from robobpp.db import work
from robobpp.db.migrate import upgrade
from robobpp.db.models import Participant, RunRow
from robobpp.db.session import make_engine, make_session_factory, transaction
from robobpp.export import SUMMARY_DECIMALS
from robobpp.scoring.scores import ANCHORS_VERSION
from robobpp.sim import MATH_RULES_VERSION
from tests.server.conftest import ADMIN_TOKEN, complete_next_episode, new_participant, wait_for


@pytest.fixture
def factory(tmp_path):
    url = f"sqlite:///{tmp_path / 'provenance.db'}"
    engine = make_engine(url)
    upgrade(url, engine=engine)
    yield make_session_factory(engine)
    engine.dispose()


def _finished(factory, name: str, rules: str | None, sampler: str | None) -> int:
    with transaction(factory) as s:
        p = s.execute(select(Participant).where(Participant.name == "p")).scalar_one_or_none()
        if p is None:
            p = Participant(name="p")
            s.add(p)
            s.flush()
        sub = work.create_submission(
            s, p, name=name, policy_url="builtin:dbl", datasets=["diverse"], settings=["math"], groups=2
        )
        sub_id = sub.id
    for _ in range(2):
        metrics = {"space_utilization": 0.5, "occupancy": 0.9, "decision_time": 0.01}
        complete_next_episode(factory, metrics, rules_version=rules, sampler_version=sampler)
    return sub_id


def test_a_board_shows_only_the_current_math_rules_and_sampler(factory) -> None:
    now = _finished(factory, "now", MATH_RULES_VERSION, SAMPLER_VERSION)
    _finished(factory, "old rules", "0", SAMPLER_VERSION)
    # Sampler 1 drew Repetitive's private groups as windows of the public test pool: never beside version 2.
    _finished(factory, "sampler 1", MATH_RULES_VERSION, "1")
    hand_built = _finished(factory, "boxes not drawn by the sampler", MATH_RULES_VERSION, None)
    before = _finished(factory, "before versions", MATH_RULES_VERSION, SAMPLER_VERSION)
    with transaction(factory) as s:  # a run recorded before 0008 has no provenance: version 1 of both
        run = s.execute(select(RunRow).where(RunRow.submission_id == before)).scalar_one()
        run.extras = {k: v for k, v in (run.extras or {}).items() if k != "provenance"}
    with transaction(factory) as s:
        recorded = s.execute(select(RunRow.extras).where(RunRow.submission_id == now)).scalar_one()[
            "provenance"
        ]
        names = sorted(e["name"] for e in leaderboard(s, "diverse", "math", track="private").entries)
    assert SAMPLER_VERSION == "2"  # what "before versions" (version 1) and "sampler 1" are kept apart from
    assert names == ["boxes not drawn by the sampler", "now"], hand_built
    assert recorded == {
        **provenance.environment(),
        "physics": None,
        "math_rules": MATH_RULES_VERSION,
        "sampler": SAMPLER_VERSION,
        "protocol": "closed",
    }


def test_submissions_runs_boards_and_exports_carry_provenance(make_server, policy_server, tmp_path) -> None:
    server = make_server(f"sqlite:///{tmp_path / 'prov.sqlite3'}", ROBOBPP_DATASETS='["diverse"]')
    policy = policy_server()
    with server.client(ADMIN_TOKEN) as admin:
        token = new_participant(admin, "alice")
        with server.client(token) as alice:
            ids = [
                alice.post(
                    "/submissions",
                    json={"name": f"run {i}", "policy_url": policy.url, "secret": "policy-secret-123"},
                ).json()["id"]
                for i in (1, 2)
            ]

            def finished() -> list[dict[str, Any]] | None:
                subs = [alice.get(f"/submissions/{i}").json() for i in ids]
                return subs if all(s["status"] == "completed" for s in subs) else None

            subs = wait_for(finished, 120)
        board = wait_for(
            lambda: (
                (b := admin.get("/leaderboards/diverse/math", params={"view": "all"}).json())["total"] == 3
                and b
            ),
            60,
        )
        (baseline,) = [e["submission_id"] for e in board["entries"] if e["baseline"]]
        page = admin.get(f"{server.url}/submissions/{baseline}", headers={"Accept": "text/html"}).text
        shown = admin.get(f"{server.url}/boards/diverse/math").text
    prov = subs[0]["provenance"]
    assert (prov["robobpp"], prov["commit"]) == (robobpp.__version__, provenance.git_commit())
    assert "datasets_manifest_sha256" in prov and prov["physics"] is None
    assert (prov["math_rules"], prov["sampler"], prov["anchors"]) == (
        MATH_RULES_VERSION,
        None,
        ANCHORS_VERSION,
    )  # offline boxes
    assert (prov["protocol"], prov["split"], prov["seed"], prov["groups"]) == ("closed", "test", None, 2)
    assert subs[0]["runs"][0]["extras"]["provenance"]["math_rules"] == MATH_RULES_VERSION
    counts = {e["name"]: (e["entries_submitted"], e["best"]) for e in board["entries"]}
    assert counts.pop("run 1")[0] == counts.pop("run 2")[0] == 2 and list(counts.values()) == [(1, True)]
    assert all(e["extras"]["provenance"]["math_rules"] == MATH_RULES_VERSION for e in board["entries"])
    assert shown.count('data-role="entries-submitted"') == 1 and "best of 2" in shown  # the best view
    assert 'id="provenance"' in page and "math_rules" in page and "secret (the test draw)" in page

    from robobpp.cli import app, register_commands

    register_commands()
    env = {"ROBOBPP_SERVER": server.url, "ROBOBPP_TOKEN": "", "ROBOBPP_POLICY_SECRET": ""}
    runner = CliRunner()

    def export(fmt: str, *extra: str) -> str:
        r = runner.invoke(
            app,
            ["leaderboard", "--dataset", "diverse", "--setting", "math", "--format", fmt, *extra],
            env=env,
        )
        assert r.exit_code == 0, r.output
        return r.stdout

    rows = list(csv.DictReader(io.StringIO(export("csv", "--view", "all"))))
    assert sorted(r["name"] for r in rows) == sorted(e["name"] for e in board["entries"])
    for row, entry in zip(
        sorted(rows, key=lambda r: r["submission_id"]),
        sorted(board["entries"], key=lambda e: e["submission_id"]),
        strict=True,
    ):
        # figures at the one precision of a board's CSV (SUMMARY_DECIMALS, the precision scores rank at)
        assert float(row["space_utilization"]) == round(
            entry["metrics"]["space_utilization"], SUMMARY_DECIMALS
        )
        assert float(row["space_utilization_low"]) == round(
            entry["intervals"]["space_utilization"][0], SUMMARY_DECIMALS
        )
        assert int(row["rank"]) == entry["rank"] and row["math_rules"] == MATH_RULES_VERSION
        assert int(row["entries_submitted"]) == entry["entries_submitted"]
    md = export("md")
    assert md.startswith("**math/diverse · private track**") and "| rank | entry |" in md
    assert (
        f"math_rules {MATH_RULES_VERSION}" in md and "split test" in md and "anchors " + ANCHORS_VERSION in md
    )
    tex = export("latex")
    caption = tex[tex.index("\\caption{") :]  # a relative score is quotable only with its server and date
    assert server.url in caption and f"{datetime.now(UTC).date().isoformat()} (UTC)" in caption
    assert tex.startswith("\\begin{table}\n") and export("latex", "--wide").startswith("\\begin{table*}\n")
    grid = runner.invoke(app, ["leaderboard", "--format", "md"], env=env)
    assert grid.exit_code == 0, grid.output
    assert "| rank | entry | math/diverse | mean ↑ | stable score ↑ |" in grid.stdout
    grid_rows = list(
        csv.DictReader(io.StringIO(runner.invoke(app, ["leaderboard", "--format", "csv"], env=env).stdout))
    )
    assert {r["status"] for r in grid_rows} == {"ranked"} and all(r["math/diverse_rank"] for r in grid_rows)
    bad = runner.invoke(app, ["leaderboard", "--format", "docx"], env=env)
    assert bad.exit_code == 2 and "unknown format 'docx'" in bad.output
