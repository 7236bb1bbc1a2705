"""``docker compose up`` for real: PostgreSQL, Redis, the server and two workers in containers.

On the images deploy/build-images.sh builds (no registry needed) and host networking (a daemon that leaves the
firewall alone). One pass, in the order an operator meets it: the stack comes up healthy with the migrations
applied once; the operator creates a participant and submits a built-in policy, which is ranked; a worker
container is killed with SIGKILL mid-evaluation and its episode runs again, nothing lost or counted twice;
``docker compose down`` and ``up`` keep every result. The figures it prints are the ones in docs/deploy.md.
"""

from __future__ import annotations

import subprocess
import time
from typing import Any

import httpx
import pytest

from tests.deploy.conftest import Stack

pytestmark = [pytest.mark.docker, pytest.mark.timeout(1500)]
MIGRATION = "Running upgrade"  # alembic's line for each migration it applies


def wait(predicate: Any, timeout: float, what: str, stack: Stack) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.5)
    pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}\n{stack.logs()}")


def board(stack: Stack, setting: str) -> dict[str, Any]:
    return stack.api("GET", f"/leaderboards/repetitive/{setting}")


def results(stack: Stack, subs: list[int]) -> dict[str, Any]:
    """What a participant or the operator can read back: submissions, episodes and the boards."""
    keep = ("id", "status", "attempts", "group", "boxes_placed", "metrics", "termination")
    return {
        "submissions": [
            {k: v for k, v in stack.api("GET", f"/submissions/{s}").items() if k != "progress"} for s in subs
        ],
        "episodes": [
            [{k: e[k] for k in keep} for e in stack.api("GET", f"/submissions/{s}/episodes")] for s in subs
        ],
        "boards": {
            setting: [(e["submission_id"], e["rank"], e["metrics"]) for e in board(stack, setting)["entries"]]
            for setting in ("math", "execution")
        },
    }


def test_compose_stack_ranks_survives_a_killed_worker_and_a_restart(stack: Stack) -> None:
    t = stack.timings
    # --- up from nothing: images only, empty volumes
    t0 = time.monotonic()
    stack.compose("up", "-d", "--scale", "worker=2")
    stack.wait_healthy(workers=2)
    t["up: all five containers healthy"] = time.monotonic() - t0
    health = httpx.get(stack.url + "/healthz", timeout=10).json()
    assert health == {"status": "ok", "database": "ok", "workers": 2}
    server_log = stack.logs("server", tail="all")
    applied = server_log.count(MIGRATION)
    assert applied >= 6, server_log  # every migration, by the server
    assert MIGRATION not in stack.logs("worker", tail="all")  # only the server migrates

    # --- the operator creates a participant; its token works
    created = stack.api("POST", "/participants", json={"name": "smoke-participant"})
    me = stack.api("GET", "/me", token=created["token"])
    assert me["participant"]["name"] == "smoke-participant" and not me["admin"]

    # --- a built-in policy (Math, the cheap setting) is submitted and ranked
    t1 = time.monotonic()
    math = stack.api(
        "POST",
        "/submissions",
        json={
            "name": "dbl-math",
            "policy_url": "builtin:dbl",
            "datasets": ["repetitive"],
            "settings": ["math"],
        },
    )
    entry = wait(lambda: board(stack, "math")["entries"], 300, "the Math submission on the board", stack)[0]
    t["submit -> ranked (Math, 3 episodes)"] = time.monotonic() - t1
    t["up -> first ranked result"] = time.monotonic() - t0
    assert entry["submission_id"] == math["id"] and entry["rank"] == 1
    assert entry["extras"]["episodes"] == 3

    # --- Execution: one worker container is killed with SIGKILL while both run an episode (Execution, whose
    # robot plans every move, so an episode lasts long enough to be caught mid-way: since physics version 4 a
    # Physics DBL episode collapses within about 2 s and the two workers were never seen mid-episode together)
    t2 = time.monotonic()
    execution = stack.api(
        "POST",
        "/submissions",
        json={
            "name": "dbl-execution",
            "policy_url": "builtin:dbl",
            "datasets": ["repetitive"],
            "settings": ["execution"],
        },
    )

    def both_mid_episode() -> bool:
        eps = stack.api("GET", f"/submissions/{execution['id']}/episodes")
        return sum(e["status"] == "running" for e in eps) == 2  # short episodes: progress may not show yet

    wait(both_mid_episode, 300, "two Execution episodes mid-way", stack)
    victim = stack.containers("worker")[0]
    subprocess.run(
        ["docker", "kill", "--signal", "KILL", victim], check=True, capture_output=True, timeout=60
    )
    killed = time.monotonic()

    def done() -> dict[str, Any] | None:
        sub = stack.api("GET", f"/submissions/{execution['id']}")
        return sub if sub["status"] in ("completed", "failed", "cancelled") else None

    sub = wait(done, 600, "the Execution submission to finish", stack)
    t["kill -9 -> submission complete"] = time.monotonic() - killed
    t["submit -> ranked (Execution, 3 episodes, one killed)"] = time.monotonic() - t2
    assert sub["status"] == "completed", sub
    eps = stack.api("GET", f"/submissions/{execution['id']}/episodes")
    assert sorted(e["group"] for e in eps) == [0, 1, 2]  # nothing lost, nothing doubled
    assert all(e["status"] == "done" and e["metrics"] for e in eps), eps
    assert sorted(e["attempts"] for e in eps) == [1, 1, 2], eps  # the killed one ran again, once
    entry = next(e for e in board(stack, "execution")["entries"] if e["submission_id"] == execution["id"])
    assert entry["extras"]["episodes"] == 3
    before = results(stack, [math["id"], execution["id"]])

    # --- down and up again: every result is still there; no migration runs again
    t3 = time.monotonic()
    stack.compose("down")
    t["down"] = time.monotonic() - t3
    t4 = time.monotonic()
    stack.compose("up", "-d", "--scale", "worker=2")
    stack.wait_healthy(workers=2)
    t["up again (volumes kept): all healthy"] = time.monotonic() - t4
    assert MIGRATION not in stack.logs("server", tail="all")
    assert results(stack, [math["id"], execution["id"]]) == before
    assert stack.api("GET", "/me", token=created["token"])["participant"]["name"] == "smoke-participant"

    print("\ncompose stack timings (s):")
    for what, seconds in t.items():
        print(f"  {what:<52} {seconds:7.1f}")
