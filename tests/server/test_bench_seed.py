"""The benchmarks' bulk seeding (bench/_seed.py) writes what the server's worker would have stored: each
run's aggregate metrics, side figures, per-group figures and scoring part recomputed here from the episode
rows it wrote, with robobpp's own functions, on SQLite and PostgreSQL."""

from __future__ import annotations

import importlib
from pathlib import Path

from sqlalchemy import select

from robobpp.db.models import EpisodeRow, RunRow, Submission
from robobpp.db.work import run_figures
from robobpp.provenance import recorded_rules
from robobpp.replay import paper_settings
from robobpp.scoring.entries import part_of_run
from robobpp.scoring.stats import group_figures
from robobpp.server.bootstrap import bootstrap
from robobpp.server.config import Settings
from robobpp.server.runtime import Runtime

# By name: mypy checks bench/_seed.py as `_seed`, the module its scripts import (they run from bench/).
_seed = importlib.import_module("bench._seed")


def runtime_for(url: str, tmp_path: Path) -> Runtime:
    runtime = Runtime(
        Settings(
            database_url=url,
            state_dir=tmp_path,
            workers=0,
            evaluate_baselines=False,
            settings=_seed.SETTINGS,
            groups=_seed.GROUPS,
            spec_provider="robobpp.worker.specs:offline_spec",
        )
    )
    bootstrap(runtime)
    return runtime


def _utilisation(run: RunRow) -> float:
    assert run.metrics is not None
    return run.metrics["space_utilization"]


def test_seeded_runs_are_what_a_worker_stores(db_url: str, tmp_path: Path) -> None:
    runtime = runtime_for(db_url, tmp_path)
    try:
        stats = _seed.seed(runtime, 60, episodes_every=10, newest=5, progress=False)
        more = _seed.seed(runtime, 1, first=60, fixed_quality=1.0, progress=False)
        with runtime.read_session() as s:
            subs = s.execute(select(Submission).order_by(Submission.id)).scalars().all()
            runs = s.execute(select(RunRow).order_by(RunRow.id)).scalars().all()
            episodes = s.execute(select(EpisodeRow).order_by(EpisodeRow.id)).scalars().all()
            by_run: dict[int, list[EpisodeRow]] = {}
            for e in episodes:
                by_run.setdefault(e.run_id, []).append(e)
            assert [x.id for x in subs] == list(range(1, 62))
            kinds = {x.id: _seed.kind_of(x.id - 1) for x in subs}
            assert {x.id for x in subs if x.status == "failed"} == {
                k for k, v in kinds.items() if v == "failed"
            }
            for x in subs:
                settings = ["math"] if kinds[x.id] == "partial" else list(_seed.SETTINGS)
                assert x.settings == settings
                boards = len(settings) + len(paper_settings(settings, "private"))
                assert len(x.runs) == boards * len(_seed.DATASETS)
                assert x.episodes_total == boards * len(_seed.DATASETS) * _seed.GROUPS
            assert stats.runs + more.runs == len(runs)
            # episode rows: every 10th submission and the newest 5 of each call
            with_episodes = {e.submission_id for e in episodes}
            assert with_episodes == {i + 1 for i in range(60) if i % 10 == 0 or i >= 55} | {61}
            assert stats.episodes + more.episodes == len(episodes)
            checked = 0
            for run in runs:
                rows = by_run.get(run.id)
                if rows is None:
                    continue
                assert len(rows) == _seed.GROUPS
                assert all(e.submission_id == run.submission_id and e.setting == run.setting for e in rows)
                metrics, extras = run_figures(
                    [(e.metrics, e.counters, e.termination, e.boxes_placed) for e in rows], run.setting
                )
                figures = group_figures(
                    ({**(e.metrics or {}), **(e.counters or {}), "group": e.group} for e in rows), run.setting
                )
                assert run.metrics == metrics
                assert run.extras == {**extras, "provenance": recorded_rules()}
                assert run.figures == figures
                assert run.entry == part_of_run(figures, run.setting)
                checked += 1
            assert checked == len({e.run_id for e in episodes}) > 100
            # fixed quality 1 (bench_boards' new best) is near the top of the drawn ones
            best = runs[-1]
            assert best.submission_id == 61
            others = sorted(_utilisation(r) for r in runs[:-1] if r.setting == best.setting)
            assert _utilisation(best) > others[int(0.9 * len(others))]
    finally:
        runtime.dispose()
