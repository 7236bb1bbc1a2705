"""On a real server (``robobpp serve``, real worker processes, policies served over HTTP by the SDK): the
built-in DBL and the same DBL served by a participant place alike and are not ranked apart on any board,
whatever milliseconds of protocol and machine noise separate their Decision Times; the same placements
thinking 0.2 s a box rank below both, in every resample.

Why 0.2 s proves the point while the issue asks for 10 times the robot's cycle (a cycle is about 10 s,
3600 / picks per hour): it is 10 times the floor (scores.DECISION_FLOOR_S, 20 ms), and above the floor the loss
grows with the time (a cycle-long decision loses Decision Time's whole weight), so any longer thinker ranks below
as this one does. (With 4 episodes of a participant in flight, the default before, the SDK's one-at-a-time
server made a 0.2 s thinker measure 91-143 ms: its probes queued behind the other episodes' decisions; one in
flight, the default now, measures it as it is: the last test below.) The row printed on failure shows the round
trip and the network estimate behind each figure. The test stays about a minute (4 groups of 12 boxes per
dataset, the thinker's episodes one at a time)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import httpx
import pytest

from robobpp.core import Action, Observation
from robobpp.policies.dbl import DBL
from tests.server.conftest import POLICY_SECRET as SECRET
from tests.server.conftest import new_participant, wait_for

DATASETS = ("repetitive", "diverse", "longboard")
GROUPS = 4
THINK_S = 0.2


class ThinkingDBL(DBL):
    """DBL's placements, decided after ``THINK_S``."""

    def act(self, obs: Observation) -> Action | None:
        time.sleep(THINK_S)
        return super().act(obs)


def _submit(client: httpx.Client, name: str, url: str) -> int:
    r = client.post(
        "/submissions",
        json={
            "name": name,
            "policy_url": url,
            "secret": SECRET,
            "datasets": list(DATASETS),
            "settings": ["math"],
        },
    )
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


def _row(e: dict[str, Any]) -> str:
    m = e["metrics"]
    return (
        f"{e['name']}: rank {e['rank']} [{e['rank_low']}–{e['rank_high']}] score {e['score']:.4f} "
        f"stable {e['stable']:.4f} utilisation {m['space_utilization']:.4f} "
        f"decision {1000 * m['decision_time']:.2f} ms (round trip {_ms(m.get('round_trip'))}, "
        f"network {_ms(m.get('network_estimate'))})"
    )


def _completed(client: httpx.Client, sid: int) -> Callable[[], bool]:
    return lambda: client.get(f"/submissions/{sid}").json()["status"] == "completed"


def _ms(value: object) -> str:
    return f"{1000 * value:.2f} ms" if isinstance(value, float) else "-"


def test_served_and_builtin_dbl_are_not_apart_and_a_slow_one_ranks_below(
    db_url: str, make_server: Any, own_process: Callable[[str], str]
) -> None:
    server = make_server(db_url, ROBOBPP_GROUPS=str(GROUPS), ROBOBPP_PUBLIC_BASELINES="0")
    admin = server.client()
    alice = server.client(new_participant(admin, "alice"))
    bob = server.client(new_participant(admin, "bob"))
    served = _submit(alice, "served dbl", own_process("robobpp.policies.dbl:DBL"))
    slow = _submit(bob, "thinking dbl", own_process(f"{__name__}:ThinkingDBL"))
    for client, sid in ((alice, served), (bob, slow)):
        wait_for(_completed(client, sid), 240)

    def boards() -> dict[str, list[dict[str, Any]]] | None:
        out = {}
        for d in DATASETS:
            entries = alice.get(f"/leaderboards/{d}/math").json()["entries"]
            if len(entries) < 3 or any(e["rank_low"] is None for e in entries):
                return None  # the baseline still running, or the board not yet updated
            out[d] = entries
        return out

    found = wait_for(boards, 240)
    tables = {d: f"{d}/math:\n" + "\n".join(_row(e) for e in entries) for d, entries in found.items()}
    print("\n".join(tables.values()))
    for d, entries in found.items():
        table = tables[d]
        baseline = next(e for e in entries if e["baseline"])
        mine = next(e for e in entries if e["submission_id"] == served)
        thinker = next(e for e in entries if e["submission_id"] == slow)
        # the same placements: what is compared is Decision Time alone (a mean summed in the order the episodes
        # finished may differ in the last bit: scores.EQUAL_DECIMALS)
        for e in (mine, thinker):
            for key in ("space_utilization", "occupancy"):
                assert e["metrics"][key] == pytest.approx(baseline["metrics"][key], rel=1e-12, abs=0), table
        assert mine["rank_low"] <= baseline["rank_high"] and baseline["rank_low"] <= mine["rank_high"], table
        assert thinker["rank"] > max(mine["rank"], baseline["rank"]), table
        assert thinker["rank_low"] > max(mine["rank_high"], baseline["rank_high"]), table
        assert thinker["stable"] < min(mine["stable"], baseline["stable"]), table


def test_a_policy_server_answering_one_request_at_a_time_is_timed_for_its_own_decisions(
    make_server, policy_server, tmp_path
) -> None:
    """The SDK's server answers one request at a time. With the server's defaults a participant has one
    episode in flight, so each episode's Decision Time is the policy's THINK_S (0.2 s) a box; with several in flight on
    that server (``PARTICIPANT_MAX_RUNNING`` above 1) an /act waits for the other episodes' decisions and the
    echo probes queue behind them, and the figure was off by far more than the bounds below."""
    import json

    from tests.server.conftest import db_rows

    db_url = f"sqlite:///{tmp_path / 'one.sqlite3'}"
    server = make_server(db_url, ROBOBPP_EVALUATE_BASELINES="0", ROBOBPP_GROUPS="4")
    client = server.client(new_participant(server.client()))
    r = client.post(
        "/submissions",
        json={
            "name": "fifth",
            "policy_url": policy_server(ThinkingDBL).url,
            "secret": SECRET,
            "datasets": ["diverse"],
            "settings": ["math"],
        },
    )
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    wait_for(
        lambda: client.get(f"/submissions/{sid}").json()["status"] == "completed", timeout_s=180, every_s=0.5
    )
    rows = db_rows(db_url, "SELECT metrics FROM episodes WHERE submission_id = :s", s=sid)
    metrics = [json.loads(m) if isinstance(m, str) else m for (m,) in rows]
    assert len(metrics) == 4
    figures = [(m["decision_time"], m["round_trip"], m["network_estimate"]) for m in metrics]
    for decision, _, network in figures:
        assert 0.18 <= decision <= 0.3, figures  # 0.2 s of sleep, DBL's milliseconds, the machine's noise
        assert network < 0.05, figures  # the probes did not wait behind a decision
