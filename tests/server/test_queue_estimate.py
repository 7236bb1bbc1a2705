"""The queue's estimate against what happened, on a real server (``robobpp serve``, 2 worker slots, policies
served in processes of their own): a participant whose policy thinks 1 s a box holds both slots, a second
participant submits, and the start the API estimates right after the submission is compared with the start
its first episode got.

The tolerance is the one docs/server.md documents: the actual start within [estimate / 2 - 3 s,
2 x estimate + 3 s]. The estimate before issue 38 (a mean over the last finished episodes, whoever's: here a
fast participant's) said 0.5 s while the wait was 17.0 s; this one said 15.6 s for 17.1 s.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from datetime import datetime
from typing import Any

import httpx
import pytest

from robobpp.core import Action, Observation
from robobpp.policies.dbl import DBL
from tests.server.conftest import POLICY_SECRET, db_rows, new_participant, wait_for

THINK_S = 1.0
#: The documented tolerance: actual start within [estimate / FACTOR - SLACK_S, FACTOR x estimate + SLACK_S].
FACTOR = 2.0
SLACK_S = 3.0


class OneSecondDBL(DBL):
    """DBL's placements, each decided after ``THINK_S``."""

    def act(self, obs: Observation) -> Action | None:
        time.sleep(THINK_S)
        return super().act(obs)


def _submit(client: httpx.Client, name: str, url: str, datasets: list[str]) -> int:
    r = client.post(
        "/submissions",
        json={
            "name": name,
            "policy_url": url,
            "secret": POLICY_SECRET,
            "datasets": datasets,
            "settings": ["math"],
        },
    )
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


def _when(value: object) -> datetime:
    return value if isinstance(value, datetime) else datetime.fromisoformat(str(value))


def _episodes(db_url: str, sid: int, status: str) -> list[Any]:
    return db_rows(
        db_url,
        "SELECT step, started_at FROM episodes WHERE submission_id = :s AND status = :t",
        s=sid,
        t=status,
    )


@pytest.mark.parametrize("per_worker", [1, 16], ids=["one-episode-per-worker", "multiplexed"])
def test_estimated_start_is_within_the_documented_tolerance(
    make_server: Any, own_process: Callable[[str], str], tmp_path: Any, per_worker: int
) -> None:
    """With one episode per worker the slow participant's two episodes hold both workers and the second
    waits; multiplexed (the default), they wait on their policy and the workers take the second participant's
    episode at once: the estimate must say so rather than price the slow episodes."""
    db_url = f"sqlite:///{tmp_path / 'eta.sqlite3'}"
    server = make_server(
        db_url,
        ROBOBPP_EVALUATE_BASELINES="0",
        ROBOBPP_GROUPS="3",
        ROBOBPP_EPISODES_PER_WORKER=str(per_worker),
        ROBOBPP_PARTICIPANT_MAX_RUNNING="2",  # the slow participant holds 2 episodes, multiplexed or not
    )
    admin = server.client()
    fast = server.client(new_participant(admin, "fast"))
    slow = server.client(new_participant(admin, "slow"))
    second = server.client(new_participant(admin, "second"))
    quick_url = own_process("robobpp.policies.dbl:DBL")
    # History: a fast participant's episodes finish first (what a recent mean over everyone's would read).
    done = _submit(fast, "quick", quick_url, ["diverse"])
    wait_for(lambda: fast.get(f"/submissions/{done}").json()["status"] == "completed", timeout_s=120)
    # The slow participant holds both slots, its episodes a few boxes in (12 boxes each: about 12 s).
    many = _submit(slow, "thinking", own_process(f"{__name__}:OneSecondDBL"), ["diverse", "repetitive"])
    wait_for(
        lambda: (
            (rows := _episodes(db_url, many, "running")) and len(rows) == 2 and min(r[0] for r in rows) >= 2
        ),
        timeout_s=120,
        every_s=0.05,
    )
    mine = _submit(second, "next", quick_url, ["diverse"])
    queue = second.get(f"/submissions/{mine}").json()["queue"]
    if queue is None and per_worker > 1:  # already running: a worker took it before the question
        queue = {"position": 1, "estimated_start_s": 0.0}
    wait_for(
        lambda: db_rows(db_url, "SELECT min(started_at) FROM episodes WHERE submission_id = :s", s=mine)[0][0]
    )
    (first_start,) = db_rows(db_url, "SELECT min(started_at) FROM episodes WHERE submission_id = :s", s=mine)[
        0
    ]
    (created,) = db_rows(db_url, "SELECT created_at FROM submissions WHERE id = :s", s=mine)[0]
    actual = (_when(first_start) - _when(created)).total_seconds()
    assert queue is not None and queue["position"] == 1, queue
    estimate = queue["estimated_start_s"]
    print(f"estimated start {estimate} s, actual start {actual:.1f} s")  # the figures the report quotes
    assert estimate is not None, queue
    low, high = estimate / FACTOR - SLACK_S, FACTOR * estimate + SLACK_S
    assert low <= actual <= high, (
        f"estimated {estimate} s, started after {actual:.1f} s (tolerance {low:.1f}-{high:.1f})"
    )
    for sid, client in ((many, slow), (mine, second)):
        client.post(f"/submissions/{sid}/cancel")


def test_start_after_places_the_work_ahead_on_the_slots_as_they_free() -> None:
    from robobpp.db.waiting import start_after

    assert start_after([], 2, []) == 0  # a free slot
    assert start_after([30.0, 10.0], 2, []) == 10  # the first running episode to end
    # two participants ahead, one episode each, in turn: the slot free at 10 takes both (10+5, then 15+20),
    # so the next one frees at 30
    assert start_after([30.0, 10.0], 2, [(5.0, 1), (20.0, 1)]) == 30
    assert start_after([], 3, [(10.0, 3)]) == 10  # three free slots, three episodes ahead
    # beyond the simulated ones, the work is spread over the pool
    assert start_after([], 2, [(1.0, 100_010)]) == 50_005
