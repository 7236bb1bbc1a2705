"""A submission's own page shows its results as the boards do (issue 37, item 6): the rank with its rank
interval, the relative and the stable score with their intervals, each metric's interval, what they mean, and,
for an entry ranked apart, why it has none. Every figure is the published board's own (the API's
``?submission=`` answer), formatted by the boards' helpers. A real app on SQLite, episodes run by a real
worker unit (a failing policy served over HTTP)."""

from __future__ import annotations

import html
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from robobpp.server.app import create_app
from robobpp.server.bootstrap import bootstrap
from robobpp.server.config import Settings
from robobpp.web import fmt_metric, fmt_num
from robobpp.web.tables import metric_span, rank_span, span
from robobpp.worker.options import worker_options
from robobpp.worker.run import claim_and_run
from tests.server.conftest import submit_direct
from tests.server.test_board import NaNPolicy

ADMIN_TOKEN = "results-admin-token-0123456789abcdef"
ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
GROUPS = 2
#: Heuristics that place these episodes alike (the same utilisation): ranked apart by the noise of their
#: decision times, so their rank intervals overlap.
ALIKE = ("hm", "lsah", "packe-rules")


@pytest.fixture
def world(tmp_path: Path, policy_server: Any) -> Iterator[tuple[TestClient, dict[str, int]]]:
    """One Math board (diverse): five ranked entries (three heuristics that place alike, so their rank
    intervals overlap), a partial one (1 group of 2) and a failed one."""
    settings = Settings(
        database_url=f"sqlite:///{tmp_path / 'results.sqlite3'}",
        state_dir=tmp_path,
        admin_token=ADMIN_TOKEN,
        workers=0,
        evaluate_baselines=False,
        settings=("math",),
        datasets=("diverse",),
        groups=GROUPS,
        allow_private_policy_urls=True,
        board_refresh_s=0,
        spec_provider="robobpp.worker.specs:offline_spec",
    )
    app = create_app(settings, start_workers=False)
    bootstrap(app.state.runtime)
    one = ("diverse",)
    ids = {
        "dbl": submit_direct(app, "alice", "builtin:dbl", datasets=one, groups=GROUPS),
        "random": submit_direct(app, "bob", "builtin:random", datasets=one, groups=GROUPS),
        **{p: submit_direct(app, p, f"builtin:{p}", datasets=one, groups=GROUPS) for p in ALIKE},
        "partial": submit_direct(app, "carol", "builtin:hm", datasets=one, groups=1),
        "failed": submit_direct(
            app, "mallory", policy_server(NaNPolicy, secret=None).url, datasets=one, groups=GROUPS
        ),
    }
    runtime = app.state.runtime
    while claim_and_run(runtime.session_factory, worker_options(runtime.settings), "test:host:1") is not None:
        pass
    with TestClient(app) as client:
        signed = client.post(
            "/sign-in",
            data={"token": ADMIN_TOKEN, "csrf": _csrf(client.get("/sign-in").text)},
            follow_redirects=False,
        )
        assert signed.status_code == 303, signed.text
        yield client, ids
    runtime.dispose()


def _csrf(page: str) -> str:
    found = re.search(r'name="csrf" value="([^"]+)"', page)
    assert found is not None
    return found.group(1)


def _cell(page: str, role: str) -> str:
    """The text of the results table's one cell ``data-role=role`` (or ``data-key``), tags dropped."""
    found = re.findall(rf'<td data-(?:role|key)="{role}">(.*?)</td>', page, flags=re.S)
    assert len(found) == 1, (role, found)
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", found[0])).split())


def _on_board(client: TestClient, sid: int) -> dict[str, Any]:
    """The published board as the API serves it for one submission (what the CLI reads too)."""
    r = client.get("/api/v1/leaderboards/diverse/math", params={"view": "all", "submission": sid})
    assert r.status_code == 200, r.text
    return dict(r.json())


def test_the_page_shows_the_boards_intervals_and_the_stable_score(world: Any) -> None:
    client, ids = world
    full = client.get("/api/v1/leaderboards/diverse/math", params={"view": "all"}).json()
    ranked = full["total"]
    assert ranked == 2 + len(ALIKE) and all(
        e["rank_low"] is not None for e in full["entries"]
    )  # a small board
    # one whose rank interval is not its rank alone, so that the page must show it
    sid = next((e["submission_id"] for e in full["entries"] if e["rank_low"] < e["rank_high"]), None)
    assert sid is not None, [(e["name"], e["rank_low"], e["rank_high"]) for e in full["entries"]]
    board = _on_board(client, sid)
    (entry,) = board["entries"]
    page = client.get(f"/submissions/{sid}").text
    rank = rank_span(entry["rank"], entry["rank_low"], entry["rank_high"])
    assert _cell(page, "rank") == f"{rank} of {ranked}"
    assert (
        _cell(page, "score") == f"{fmt_num(entry['score'])} {span(entry['score_low'], entry['score_high'])}"
    )
    stable = f"{fmt_num(entry['stable'])} {span(entry['stable_low'], entry['stable_high'])}"
    assert _cell(page, "stable") == stable and entry["stable_low"] < entry["stable_high"]
    for key in board["metrics"]:  # each metric in its unit, the board's interval under it
        low, high = entry["intervals"][key]
        assert _cell(page, key) == f"{fmt_metric(entry['metrics'][key], key)} {metric_span(low, high, key)}"
    note = _cell_free(page, "interval-note")
    assert f"bootstrap 95 % interval over the board's {GROUPS} groups (1000 seeded resamples)" in note
    assert "a rank “3 (2–5)” means rank 3, and 2 to 5 in 95 % of resamples" in note
    assert "never moves when others arrive" in note
    # the board page says the same in the same words (one macro)
    board_page = " ".join(html.unescape(client.get("/boards/diverse/math").text).split())
    assert note.split("Under each figure: ")[1] in board_page


def test_an_entry_ranked_apart_says_why_it_has_no_interval(world: Any) -> None:
    client, ids = world
    for name, status in (("partial", "partial"), ("failed", "failed")):
        (apart,) = _on_board(client, ids[name])["unranked"]
        assert apart["status"] == status
        page = client.get(f"/submissions/{ids[name]}").text
        assert _cell(page, "rank") == f"not ranked: {status} {apart['reason']}; no score, rank or interval"
        assert _cell(page, "score") == _cell(page, "stable") == "—"
        assert 'data-role="interval-note"' not in page  # no interval shown: nothing to explain
    assert "ran 1 of the board's 2 groups" in _cell(client.get(f"/submissions/{ids['partial']}").text, "rank")


def _cell_free(page: str, role: str) -> str:
    found = re.search(rf'<p class="small" data-role="{role}">(.*?)</p>', page, flags=re.S)
    assert found is not None, role
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", found.group(1))).split())
