"""The board engine: what ``update`` returns equals a from-scratch computation of the same database, and only
what changed is returned."""

from __future__ import annotations

import random
from collections.abc import Iterator
from typing import Any

import pytest

from robobpp.db.migrate import upgrade
from robobpp.db.models import Participant, RunRow, Submission, utcnow
from robobpp.db.session import make_engine, make_session_factory, transaction
from robobpp.db.work import run_figures
from robobpp.scoring.stats import group_figures
from robobpp.server.services.board_engine import BoardEngine, compute_snapshot

DATASETS = ("diverse", "longboard")
SETTINGS = ("math", "physics")
GROUPS = 6


@pytest.fixture
def factory(db_url: str) -> Iterator[Any]:
    upgrade(db_url)
    engine = make_engine(db_url)
    yield make_session_factory(engine)
    engine.dispose()


def episode(rng: random.Random, quality: float, setting: str, group: int) -> dict[str, Any]:
    u = min(1.0, max(0.0, rng.gauss(0.4 + 0.4 * quality, 0.1)))
    e: dict[str, Any] = {
        "group": group,
        "space_utilization": u,
        "occupancy": min(1.0, u + 0.2 * rng.random()),
        "decision_time": 0.001 + 0.01 * rng.random(),
    }
    if setting != "math":
        e |= {"local_stability": 0.01 * rng.random(), "static_stability": 0.8 + 0.2 * rng.random()}
    return e


def add_submission(
    factory: Any, participant: str, quality: float, *, seed: int, settings: tuple[str, ...] = SETTINGS
) -> int:
    """A finished private submission whose runs are written as a worker writes them."""
    rng = random.Random(seed)
    with transaction(factory) as s:
        p = s.query(Participant).filter_by(name=participant).one_or_none()
        if p is None:
            p = Participant(name=participant)
            s.add(p)
            s.flush()
        now = utcnow()
        sub = Submission(
            participant_id=p.id,
            name=f"{participant}-{seed}",
            policy_url="https://example.org",
            track="private",
            datasets=list(DATASETS),
            settings=list(settings),
            episodes_total=GROUPS * len(DATASETS) * len(settings),
            status="completed",
            created_at=now,
            finished_at=now,
        )
        s.add(sub)
        s.flush()
        for d in DATASETS:
            for st in settings:
                eps = [episode(rng, quality, st, g) for g in range(GROUPS)]
                metrics, extras = run_figures(
                    [({k: v for k, v in e.items() if k != "group"}, {}, "completed", 20) for e in eps], st
                )
                s.add(
                    RunRow(
                        submission_id=sub.id,
                        dataset=d,
                        setting=st,
                        protocol="closed",
                        status="completed",
                        episodes_total=GROUPS,
                        metrics=metrics,
                        extras=extras,
                        figures=group_figures(eps, st),
                        completed_at=now,
                    )
                )
        return sub.id


def scratch(factory: Any) -> dict[Any, Any]:
    with factory() as s:
        snap = compute_snapshot(s, DATASETS, SETTINGS, "private")
    return {**snap["boards"], "grid": snap["grid"], "grid-paper": snap["grid-paper"]}


def test_update_returns_every_board_first_then_only_changes_and_equals_a_fresh_computation(
    factory: Any,
) -> None:
    for i in range(5):
        add_submission(factory, f"team-{i % 3}", i / 5, seed=i)
    engine = BoardEngine(factory, DATASETS, SETTINGS)
    first = engine.update("private")
    assert set(first) == set(engine.keys())
    assert first == scratch(factory)
    assert engine.update("private") == {}
    assert engine.update("public") != {}  # a track's first call returns its (empty) boards
    new = add_submission(factory, "team-9", 1.0, seed=99)
    changed = engine.update("private")
    assert changed and changed == {k: v for k, v in scratch(factory).items() if k in changed}
    assert any(e["submission_id"] == new for e in changed[("diverse", "math")]["entries"])
    with transaction(factory) as s:
        s.delete(s.get(Submission, new))
    gone = engine.update("private")
    assert all(e["submission_id"] != new for e in gone[("diverse", "math")]["entries"])
    assert engine.current("private") == scratch(factory)
