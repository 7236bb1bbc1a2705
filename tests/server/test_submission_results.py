"""A submission's own page shows its results as the boards do (issue 37, item 6): the rank with its rank
interval, the relative and the stable score with their intervals, each metric's interval, what they mean, and,
for an entry ranked apart, why it has none. Every figure is the published board's own (the API's
``?submission=`` answer), formatted by the boards' helpers. A real app on SQLite; each episode's result is
recorded as a worker records it, with figures planned so that two entries' rank intervals overlap."""

from __future__ import annotations

import html
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from robobpp.db import work
from robobpp.db.session import transaction
from robobpp.server.app import create_app
from robobpp.server.bootstrap import bootstrap
from robobpp.server.config import Settings
from robobpp.web import fmt_metric, fmt_num
from robobpp.web.tables import metric_span, rank_span, span
from tests.server.conftest import submit_direct

ADMIN_TOKEN = "results-admin-token-0123456789abcdef"
ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
GROUPS = 2
#: Space utilisation per group. "a" is better on group 0 and "b" on group 1, so resampling the groups ranks
#: each of them first in some resamples: their rank intervals are 1–2. "c" is last in every resample. The
#: other metrics are the same for all, so no timing noise decides anything.
PLAN = {"a": (0.72, 0.50), "b": (0.50, 0.70), "c": (0.30, 0.32), "partial": (0.60,)}


def _record(factory: Any, names: dict[int, str]) -> None:
    """Every episode claimed and recorded as a worker records it: the planned figures, or (``failed``) an
    error of the policy in each."""
    while True:
        with transaction(factory) as s:
            claim = work.claim_episode(s, "w", lease_s=10, max_attempts=3)
            if claim is None:
                return
            name = names[claim.submission_id]
            failed = name == "failed"
            result: dict[str, Any] = {
                "termination": "policy_error" if failed else "completed",
                "termination_detail": "",
                "boxes_total": 3,
                "boxes_placed": 0 if failed else 3,
                "metrics": {
                    "space_utilization": 0.0 if failed else PLAN[name][claim.group],
                    "occupancy": 0.9,
                    "decision_time": 0.01,
                },
                "counters": {},
                "steps": [],
            }
            assert work.complete_episode(s, claim.episode_id, claim.token, result, keep_trace=False)


@pytest.fixture
def world(tmp_path: Path) -> Iterator[tuple[TestClient, dict[str, int]]]:
    """One Math board (diverse): three ranked entries, a partial one (1 group of 2) and a failed one; the
    operator signed in (every submission page is theirs to read)."""
    settings = Settings(
        database_url=f"sqlite:///{tmp_path / 'results.sqlite3'}",
        state_dir=tmp_path,
        admin_token=ADMIN_TOKEN,
        workers=0,
        evaluate_baselines=False,
        settings=("math",),
        datasets=("diverse",),
        groups=GROUPS,
        board_refresh_s=0,
        spec_provider="robobpp.worker.specs:offline_spec",
    )
    app = create_app(settings, start_workers=False)
    bootstrap(app.state.runtime)
    ids = {
        name: submit_direct(
            app, name, "builtin:dbl", datasets=("diverse",), groups=1 if name == "partial" else GROUPS
        )
        for name in ("a", "b", "c", "partial", "failed")
    }
    _record(app.state.runtime.session_factory, {sid: name for name, sid in ids.items()})
    with TestClient(app) as client:
        signed = client.post(
            "/sign-in",
            data={"token": ADMIN_TOKEN, "csrf": _csrf(client.get("/sign-in").text)},
            follow_redirects=False,
        )
        assert signed.status_code == 303, signed.text
        yield client, ids
    app.state.runtime.dispose()


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
    ranked = client.get("/api/v1/leaderboards/diverse/math", params={"view": "all"}).json()["total"]
    board = _on_board(client, ids["b"])
    (entry,) = board["entries"]
    assert ranked == 3 and (entry["rank_low"], entry["rank_high"]) == (1, 2)  # as planned
    page = client.get(f"/submissions/{ids['b']}").text
    rank = rank_span(entry["rank"], entry["rank_low"], entry["rank_high"])
    assert _cell(page, "rank") == f"{rank} of {ranked}" == f"{entry['rank']} (1–2) of 3"
    assert (
        _cell(page, "score") == f"{fmt_num(entry['score'])} {span(entry['score_low'], entry['score_high'])}"
    )
    stable = f"{fmt_num(entry['stable'])} {span(entry['stable_low'], entry['stable_high'])}"
    assert _cell(page, "stable") == stable and entry["stable_low"] < entry["stable_high"]
    for key in board["metrics"]:  # each metric in its unit, the board's interval under it
        low, high = entry["intervals"][key]
        assert _cell(page, key) == f"{fmt_metric(entry['metrics'][key], key)} {metric_span(low, high, key)}"
    assert _cell(page, "space_utilization") == "60.0% 50.0%–70.0%"  # b's two groups, in the board's unit
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
