"""The board engine: what ``update`` returns equals a from-scratch computation of the same database, and only
what changed is returned."""

from __future__ import annotations

import dataclasses
import gc
import json
import math
import random
import re
import struct
import weakref
from collections import UserList
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from sqlalchemy import select, text

from robobpp.boards import engine as board_engine
from robobpp.boards.engine import BoardEngine, compute_snapshot
from robobpp.boards.records import Board, Grid, Published, as_board, as_grid
from robobpp.db import work
from robobpp.db.migrate import upgrade
from robobpp.db.models import Participant, RunRow, Submission, utcnow
from robobpp.db.session import make_engine, make_session_factory, transaction
from robobpp.db.work import run_figures
from robobpp.provenance import recorded_rules
from robobpp.scoring.entries import EntryPart, entry_part, part_of_run
from robobpp.scoring.stats import group_figures
from tests.server.conftest import complete_next_episode

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
        # below the floor less the resolution (scores.DECISION_FLOOR_S, DECISION_RESOLUTION_S): with its timing
        # noise a time never leaves the floor, so an entry between two others stays between them in every resample
        "decision_time": 0.001 + 0.004 * rng.random(),
    }
    if setting != "math":
        e |= {"local_stability": 0.01 * rng.random(), "static_stability": 0.8 + 0.2 * rng.random()}
    return e


def episodes_of(quality: float, seed: int, settings: tuple[str, ...] = SETTINGS) -> dict[Any, list[Any]]:
    rng = random.Random(seed)
    return {
        (d, st): [episode(rng, quality, st, g) for g in range(GROUPS)] for d in DATASETS for st in settings
    }


def between(a: dict[Any, list[Any]], b: dict[Any, list[Any]]) -> dict[Any, list[Any]]:
    """Episodes halfway between two submissions' in every group: in every resample, its figures lie
    between theirs."""
    return {
        key: [
            {k: (x[k] + y[k]) / 2 if k != "group" else x[k] for k in x}
            for x, y in zip(a[key], b[key], strict=True)
        ]
        for key in a
    }


def add_submission(
    factory: Any,
    participant: str,
    quality: float,
    *,
    seed: int,
    settings: tuple[str, ...] = SETTINGS,
    episodes: dict[Any, list[Any]] | None = None,
    lookahead: int = 0,
    paper: bool = False,
    builtin: bool = False,
) -> int:
    """A finished private submission whose runs are written as a worker writes them (``lookahead``: next
    boxes its policy saw; ``paper``: its physical runs also under the paper protocol, with the same figures;
    ``builtin``: a built-in baseline's)."""
    episodes = episodes or episodes_of(quality, seed, settings)
    with transaction(factory) as s:
        p = s.query(Participant).filter_by(name=participant).one_or_none()
        if p is None:
            p = Participant(name=participant, is_builtin=builtin)
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
            lookahead=lookahead,
        )
        s.add(sub)
        s.flush()
        for d in DATASETS:
            for st, protocol in [(st, "closed") for st in settings] + [
                (st, "paper") for st in settings if paper and st != "math"
            ]:
                eps = episodes[(d, st)]
                metrics, extras = run_figures(
                    [({k: v for k, v in e.items() if k != "group"}, {}, "completed", 20) for e in eps], st
                )
                extras["provenance"] = recorded_rules()  # as finalize_run records it: current rules
                s.add(
                    RunRow(
                        submission_id=sub.id,
                        dataset=d,
                        setting=st,
                        protocol=protocol,
                        status="completed",
                        episodes_total=GROUPS,
                        metrics=metrics,
                        extras=extras,
                        figures=group_figures(eps, st),
                        completed_at=now,
                    )
                )
        return sub.id


def scratch(factory: Any) -> dict[Any, Published]:
    """Every board and grid of the private track computed from scratch, by engine key."""
    with factory() as s:
        return dict(compute_snapshot(s, DATASETS, SETTINGS, "private"))


def same(a: Any, b: Any, path: str = "", *, ranks: bool = True, tol: float = 0.0) -> None:
    """``a`` equals ``b``: floats within ``tol`` (0: bit for bit); without ``ranks``, the all-entries rank
    intervals of ``a`` may be None (not computed yet) or as last computed."""
    if isinstance(a, Board | Grid):
        assert type(a) is type(b), path
        for item in (a, b):
            if (
                item.ranked is not None
            ):  # the engine's arrays of the same entries: checked against the entries
                ranked_view(item)
        for f in dataclasses.fields(a):
            mine, theirs = getattr(a, f.name), getattr(b, f.name)
            if f.name == "ranked":
                continue
            if f.name == "index":  # the engine's positions read off its arrays, the reference's a dict
                mine, theirs = dict(mine), dict(theirs)
            same(mine, theirs, f"{path}/{f.name}", ranks=ranks, tol=tol)
    elif isinstance(a, dict):
        for x in (a, b):
            if "_base" in x:  # the engine's row without ranks, kept between updates: what it shows now
                served = {k: v for k, v in x.items() if not k.startswith("_") and not k.startswith("best_")}
                if "cells" in served:
                    served["cells"] = {k: {**c, "rank": None} for k, c in served["cells"].items()}
                if "cells" not in served:  # a board's row is stored without its participant's entry count
                    served.pop("entries_submitted")
                assert x["_base"] == served | {"rank": None}, path
        # without it, and which engine rows the grid's were made of
        a, b = ({k: v for k, v in x.items() if k not in ("_base", "_bases")} for x in (a, b))
        assert set(a) == set(b), (path, set(a) ^ set(b))
        for k in a:
            # the best entries' rank intervals are always current; the others (entries, grid rows and cells)
            # as of the last full computation
            if not ranks and k in ("rank_low", "rank_high") and not re.search(r"/best\[\d+\]$", path):
                continue
            same(a[k], b[k], f"{path}/{k}", ranks=ranks, tol=tol)
    elif isinstance(a, list | tuple | UserList):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same(x, y, f"{path}[{i}]", ranks=ranks, tol=tol)
    elif isinstance(a, float) and isinstance(b, float):
        assert abs(a - b) <= tol or (math.isnan(a) and math.isnan(b)), (path, a, b)
    else:
        assert a == b, (path, a, b)


def ranked_view(board: Published) -> None:
    """A board's (or the grid's) arrays show its all-entries view: ids and ranks in rank order, each
    column's row without ranks."""
    view = board.ranked
    assert view is not None
    entries = board.entries if isinstance(board, Board) else board.rows
    assert view.ids.tolist() == [e["submission_id"] for e in entries]
    assert view.ranks.tolist() == [e["rank"] for e in entries]
    by_id = {e["submission_id"]: e for e in entries}
    for column, sid in enumerate(view.ids_by_column.tolist()):
        assert view.row(column) == by_id[sid]["_base"]
        assert view.rank_by_column[column] == by_id[sid]["rank"]
    if view.cells is not None:
        assert isinstance(board, Grid)
        keys = [f"{s}/{d}" for s in board.settings for d in board.datasets]
        assert view.cells.tolist() == [[e["cells"][k]["rank"] for k in keys] for e in entries]


def view_of(item: Published) -> Any:
    assert item.ranked is not None
    return item.ranked


def full(factory: Any) -> dict[Any, Published]:
    """The track computed in full by a fresh engine."""
    return BoardEngine(factory, DATASETS, SETTINGS).update("private")


def test_first_update_equals_the_from_scratch_boards(factory: Any) -> None:
    for i in range(8):
        add_submission(factory, f"team-{i % 3}", i / 8, seed=i)
    engine = BoardEngine(factory, DATASETS, SETTINGS)
    first = engine.update("private")
    assert set(first) == set(engine.keys())
    # the reference resamples every entry at once (one matrix product), the engine each entry alone: the
    # sums differ in the last bits only
    same(first, scratch(factory), tol=1e-12)
    assert engine.update("private") == {}
    assert set(engine.update("public")) == set(engine.keys())  # a track's first call: its (empty) boards


def test_an_incremental_update_equals_the_full_computation(factory: Any) -> None:
    for i in range(10):
        add_submission(factory, f"team-{i % 4}", 0.2 + 0.6 * i / 10, seed=i)
    engine = BoardEngine(factory, DATASETS, SETTINGS)
    engine.update("private")
    matrix = engine._tracks["private"].boards[("diverse", "math")]

    # a middling entry: inside every resample's min–max, so nobody else is renormalised
    epoch = matrix.epoch
    middle = between(episodes_of(0.2, 0), episodes_of(0.2 + 0.6 * 9 / 10, 9))

    def serials(view: Any) -> dict[int, int]:
        return dict(zip(view.ids_by_column.tolist(), view.serials.tolist(), strict=True))

    grid_rows = serials(view_of(engine._tracks["private"].out["grid"]))
    middling = add_submission(factory, "team-5", 0.5, seed=100, episodes=middle)
    changed = engine.update("private")
    assert matrix.epoch == epoch, "a middling entry renormalised the board"
    # the grid rows it moved only in rank keep their serial (not serialised nor written again)
    now = serials(view_of(changed["grid"]))
    assert set(now) - set(grid_rows) == {middling}
    assert all(now[sid] == serial for sid, serial in grid_rows.items())
    same(changed, {k: v for k, v in full(factory).items() if k in changed}, ranks=False)
    new_entry = as_board(changed[("diverse", "math")]).entries
    assert any(e["submission_id"] == middling and e["rank_low"] is None for e in new_entry)

    # an entry above everyone in one group only: the maximum moves in the resamples that draw that group
    # often; only those resamples of the others are renormalised, and only the entries whose interval could
    # move are recomputed
    lifted = between(episodes_of(0.2, 0), episodes_of(0.2 + 0.6 * 9 / 10, 9))
    for d in DATASETS:
        lifted[(d, "math")][0]["space_utilization"] = 1.0
    rows_before, recomputed = matrix.shifted_rows, matrix.recomputed
    before_view = view_of(engine._tracks["private"].out[("diverse", "math")])
    rows = {sid: before_view.row(c) for c, sid in enumerate(before_view.ids_by_column.tolist())}
    before_serials = serials(before_view)
    add_submission(factory, "team-8", 0.5, seed=103, episodes=lifted)
    changed = engine.update("private")
    shifted = matrix.shifted_rows - rows_before
    assert 0 < shifted < 500 and matrix.recomputed - recomputed < len(matrix.submission_ids())
    # an entry scored again keeps its serial (not serialised nor written again) unless what it shows moved
    view = view_of(changed[("diverse", "math")])
    for c, sid in enumerate(view.ids_by_column.tolist()):
        if sid in rows:
            moved = view.row(c) != rows[sid]
            assert moved == (view.serials[c] != before_serials[sid]), f"entry {sid}"
    # a board hands out rows built from its figures as they were: the earlier board's rows did not move
    assert all(before_view.row(c) == rows[sid] for c, sid in enumerate(before_view.ids_by_column.tolist()))
    same(changed, {k: v for k, v in full(factory).items() if k in changed}, ranks=False)
    # no samples are kept per entry: the board keeps figures and a few numbers per entry
    kept = as_board(engine._tracks["private"].out[("diverse", "math")])
    assert kept.for_grid is not None and kept.for_grid.samples is None

    # a new best: it moves the maximum, every entry is renormalised
    best = add_submission(factory, "team-6", 3.0, seed=101)
    changed = engine.update("private")
    assert matrix.epoch > epoch
    same(changed, {k: v for k, v in full(factory).items() if k in changed}, ranks=False)
    assert as_board(changed[("diverse", "math")]).entries[0]["submission_id"] == best

    # a Math-only submission touches the Math boards and the grids only
    partial = add_submission(factory, "team-7", 0.5, seed=102, settings=("math",))
    changed = engine.update("private")
    assert set(changed) == {(d, "math") for d in DATASETS} | {"grid", "grid-paper"}
    assert any(r["submission_id"] == partial for r in as_grid(changed["grid"]).apart)

    # removal of the best: the maximum moves back
    with transaction(factory) as s:
        s.delete(s.get(Submission, best))
    changed = engine.update("private")
    assert all(e["submission_id"] != best for e in as_board(changed[("diverse", "math")]).entries)
    same(changed, {k: v for k, v in full(factory).items() if k in changed}, ranks=False)

    # the refresh computes every rank interval: then everything equals a full computation, bit for bit; the
    # parts it read with the runs are the boards' (none read a second time)
    loads: list[int] = []

    def counting(load: Any) -> Any:
        def counted(sids: Any) -> Any:
            loads.append(len(sids))
            return load(sids)

        return counted

    for m in engine._tracks["private"].boards.values():
        m.load = counting(m.load)
    same(engine.refresh("private"), full(factory))
    assert loads == []


def test_a_finished_run_stores_its_scoring_part(factory: Any) -> None:
    with transaction(factory) as s:
        p = Participant(name="p")
        s.add(p)
        s.flush()
        work.create_submission(
            s, p, name="x", policy_url="builtin:dbl", datasets=["diverse"], settings=["math"], groups=3
        )
    for g in range(3):
        complete_next_episode(
            factory, {"space_utilization": 0.3 + 0.1 * g, "occupancy": 0.9, "decision_time": 0.01}
        )
    with factory() as s:
        run = s.execute(select(RunRow)).scalar_one()
        assert run.status == "completed" and run.entry is not None
        stored = EntryPart.decode(run.entry, "math")
        assert stored is not None
        expected = entry_part(run.figures, "math")
        assert stored.ids.tolist() == [0, 1, 2]
        for name in ("top", "bottom", "metric_ci"):
            assert np.array_equal(getattr(stored, name), getattr(expected, name)), name
        assert stored.stable_ci == expected.stable_ci
        su = stored.metric_ci[0]
        assert 0.3 <= su[0] < su[1] <= 0.5  # the space utilisation's interval spans the groups' values


def test_the_migration_computes_the_parts_of_runs_finished_before_it(db_url: str) -> None:
    upgrade(db_url, "0009")
    engine = make_engine(db_url)
    factory = make_session_factory(engine)
    try:
        with engine.begin() as c:  # the runs table as 0009 left it: no entry column yet
            c.execute(
                text("INSERT INTO participants (name, is_builtin, created_at) VALUES ('old', false, :t)"),
                {"t": utcnow()},
            )
        ids = []
        for i in range(3):
            eps = episodes_of(i / 3, seed=i, settings=("math",))[("diverse", "math")]
            with engine.begin() as c:
                pid = c.execute(text("SELECT id FROM participants WHERE name = 'old'")).scalar_one()
                c.execute(
                    text(
                        "INSERT INTO submissions (participant_id, name, policy_url, track, datasets, settings,"
                        " lookahead, episodes_total, status, created_at, finished_at, mode)"
                        " VALUES (:p, :n, 'https://example.org', 'private', '[\"diverse\"]', '[\"math\"]', 0,"
                        " :g, 'completed', :t, :t, 'push')"
                    ),
                    {"p": pid, "n": f"old-{i}", "g": GROUPS, "t": utcnow()},
                )
                sid = c.execute(text("SELECT max(id) FROM submissions")).scalar_one()
                c.execute(
                    text(
                        "INSERT INTO runs (submission_id, dataset, setting, protocol, status, episodes_total,"
                        " figures) VALUES (:s, 'diverse', 'math', 'closed', 'completed', :g, :f)"
                    ),
                    {"s": sid, "g": GROUPS, "f": json.dumps(group_figures(eps, "math"))},
                )
                ids.append(sid)
        upgrade(db_url)
        with factory() as s:
            runs = s.execute(select(RunRow).order_by(RunRow.id)).scalars().all()
            assert len(runs) == 3
            for run in runs:
                assert run.entry == part_of_run(run.figures, "math")
    finally:
        engine.dispose()


def test_the_migration_recomputes_the_parts_of_an_older_format(db_url: str, factory: Any) -> None:
    add_submission(factory, "team-0", 0.5, seed=3)
    with factory() as s:
        runs = s.execute(select(RunRow).order_by(RunRow.id)).scalars().all()
        current = {run.id: part_of_run(run.figures, run.setting) for run in runs}
        settings = {run.id: run.setting for run in runs}
    assert len(current) >= 3
    older: dict[int, bytes | None] = {}
    for k, (run_id, entry) in enumerate(current.items()):  # as format 3 stored them (one run without any)
        assert entry is not None
        part = EntryPart.decode(entry, settings[run_id])
        assert part is not None
        old = _format_3(part)
        assert EntryPart.decode(old, settings[run_id]) is None  # not read as the current format
        older[run_id] = None if k == 0 else old
    engine = make_engine(db_url)
    try:
        with engine.begin() as c:
            for run_id, stored in older.items():
                c.execute(text("UPDATE runs SET entry = :e WHERE id = :i"), {"e": stored, "i": run_id})
            c.execute(text("UPDATE alembic_version SET version_num = '0012'"))
        upgrade(db_url)
        with factory() as s:
            after = {run_id: entry for run_id, entry in s.execute(select(RunRow.id, RunRow.entry))}
        assert after == current
    finally:
        engine.dispose()


def _format_3(part: EntryPart) -> bytes:
    """A part as format 3 stored it (float64 figures)."""
    header = struct.pack("<4sHHHH", b"RBPE", 3, part.groups, part.top.shape[1], 0)
    return b"".join(
        (
            header,
            part.ids.astype("<i8").tobytes(),
            part.top.astype("<f8").tobytes(),
            part.bottom.astype("<f8").tobytes(),
            part.metric_ci.astype("<f8").tobytes(),
            np.array(part.stable_ci, dtype="<f8").tobytes(),
            np.array([part.seed], dtype="<u8").tobytes(),
        )
    )


class _Cycle:
    """An object in a reference cycle: only the cyclic garbage collector frees it."""

    def __init__(self) -> None:
        self.me = self


def test_the_engine_computes_without_the_collector_and_frees_cycles_it_froze(
    factory: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    for i in range(4):
        add_submission(factory, f"team-{i}", 0.3 + 0.1 * i, seed=i)
    states: list[bool] = []

    def watched() -> Any:
        states.append(gc.isenabled())
        return factory()

    small = BoardEngine(factory, DATASETS, SETTINGS)
    small.update("private")
    assert gc.get_freeze_count() == 0, "a small engine froze its objects"
    monkeypatch.setattr(board_engine, "FREEZE_ENTRIES", 1)  # as a large deployment's

    engine = BoardEngine(watched, DATASETS, SETTINGS)
    assert gc.isenabled()
    try:
        garbage = _Cycle()
        gone = weakref.ref(garbage)
        del garbage  # cyclic garbage when the engine starts: collected, never frozen
        engine.update("private")  # the first: a full computation
        # what it kept is frozen (later collections skip it), the collector runs again
        assert gc.get_freeze_count() > 0 and gc.isenabled()
        assert gone() is None, "a full computation froze a cycle that was garbage already"

        add_submission(factory, "team-9", 0.5, seed=9)
        assert engine.update("private")
        assert states and not any(states), "the engine read its data with the collector running"

        # an object alive when frozen that became cyclic garbage later: the next full computation frees it
        late = _Cycle()
        late_ref = weakref.ref(late)
        add_submission(factory, "team-10", 0.5, seed=10)
        engine.update("private")
        del late
        gc.collect()
        assert late_ref() is not None, "frozen objects are not collected between full computations"
        engine.refresh("private")
        assert late_ref() is None
    finally:
        gc.unfreeze()


def test_the_engine_equals_the_from_scratch_boards_on_a_seeded_set(db_url: str, tmp_path: Any) -> None:
    """Submissions seeded as the benchmarks seed them (bench/_seed.py: three settings, the paper protocol's
    boards, pooled metrics, failed and partial entries): the engine's boards and grids equal a from-scratch
    computation after its start, after a middling and a best submission, and after a refresh."""
    from tests.server.test_bench_seed import _seed, runtime_for  # bench._seed, imported by name (see there)

    runtime = runtime_for(db_url, tmp_path)
    try:
        _seed.seed(runtime, 25, episodes_every=25, newest=1, progress=False)  # one failed, one partial

        def from_scratch() -> dict[Any, Published]:
            with runtime.read_session() as s:
                return dict(compute_snapshot(s, _seed.DATASETS, _seed.SETTINGS, "private"))

        engine = BoardEngine(runtime.read_session, _seed.DATASETS, _seed.SETTINGS)
        first = engine.update("private")
        assert len(first) == 17
        same(first, from_scratch(), tol=1e-12)
        for n, quality in ((25, 0.5), (26, 1.0)):
            _seed.seed(runtime, 1, first=n, fixed_quality=quality, progress=False)
            changed = engine.update("private")
            assert changed
            scratch_now = from_scratch()
            same(changed, {k: v for k, v in scratch_now.items() if k in changed}, ranks=False, tol=1e-12)
        same(engine.refresh("private"), from_scratch(), tol=1e-12)
    finally:
        runtime.dispose()
