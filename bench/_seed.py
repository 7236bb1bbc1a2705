"""Bulk seeding of the evaluation server's database for the benchmarks: finished submissions with their
runs (aggregate metrics, per-group figures and stored scoring part, as a worker writes them) and episodes.

What it writes is what the server would hold after evaluating them (``bench_server.py``'s docstring):
100 participants; per submission three datasets × Math, Physics and Execution closed loop and the two
physical settings again under the paper protocol (15 runs of 30 groups, 450 episodes); 2 % failed (every
episode a policy error), 2 % partial (Math Pack only). The figures are drawn around each submission's
quality (0..1).

Fast by construction (figures in ``BENCHMARKS.md``, "Seeding a large database"):

* figures drawn with numpy for a chunk of submissions at once, per setting;
* each run's aggregate metrics, per-group figures and stored part computed in bulk from those arrays. They
  are what the worker stores for the same episodes, bit for bit: a mean is a sequential sum (``cumsum``,
  as Python's ``sum``) over the count; the parts go through robobpp's own ``samples_of``, ``interval`` and
  ``stable_samples`` on the stacked runs (each is element-wise or per column, so stacking changes no bit),
  and every chunk checks one run of each setting against ``run_figures``, ``group_figures`` and
  ``part_of_run`` — a difference stops the seeding;
* PostgreSQL: ``COPY`` of all three tables, from a writer thread (the next chunk is generated while the
  database writes this one), foreign-key triggers off for the seeding connection
  (``session_replication_role = replica``: the rows are consistent by construction);
  SQLite: one ``executemany`` per table and chunk.

``episodes_every``: episode rows for one submission in that many (and always the ``newest`` 1,000 of those
seeded, so pages listing recent submissions show real progress); 1 = all. Runs and submissions are always all written.
"""

from __future__ import annotations

import io
import json
import os
import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import Any

import numpy as np
from sqlalchemy import insert, text

from robobpp.db.models import EpisodeRow, Participant, RunRow, Submission, utcnow
from robobpp.db.work import run_figures
from robobpp.provenance import recorded_rules
from robobpp.replay import paper_settings
from robobpp.scoring import stats
from robobpp.scoring.entries import (
    EntryPart,
    counts,
    metric_keys,
    part_of_run,
    part_seed,
    samples_of,
    stable_samples,
    with_timing_noise,
)
from robobpp.scoring.metrics import POOLED, metrics_for
from robobpp.scoring.stats import group_figures
from robobpp.sim.physics.config import PHYSICS_VERSION
from robobpp.vocabulary import DATASETS, SETTINGS

GROUPS = 30
TEAMS = 100
BOXES = 80  # each episode's boxes; 40 of them placed
PLACED = 40
#: Submissions generated and written at a time (≈ 90,000 episode rows).
CHUNK = 200
SEED = 20_251_126
NEWEST_WITH_EPISODES = 1000

SUBMISSION_COLUMNS = (
    "id",
    "participant_id",
    "name",
    "policy_url",
    "track",
    "mode",
    "datasets",
    "settings",
    "lookahead",
    "status",
    "episodes_total",
    "created_at",
    "finished_at",
    "error",
)
RUN_COLUMNS = (
    "id",
    "submission_id",
    "dataset",
    "setting",
    "protocol",
    "status",
    "episodes_total",
    "metrics",
    "extras",
    "figures",
    "entry",
    "completed_at",
)
EPISODE_COLUMNS = (
    "id",
    "submission_id",
    "run_id",
    "dataset",
    "setting",
    "split",
    "group",
    "status",
    "attempts",
    "step",
    "termination",
    "termination_detail",
    "boxes_total",
    "boxes_placed",
    "metrics",
    "counters",
    "finished_at",
    "physics_version",
    "protocol",
)
FAILED_ERROR = "more than 10 % of the episodes ended in a policy failure on math/repetitive"


def kind_of(i: int) -> str:
    """The ``i``-th submission (from 0): 2 % failed, 2 % partial, the rest complete."""
    return "failed" if i % 50 == 7 else "partial" if i % 50 == 23 else "ok"


@dataclass
class Stats:
    submissions: int = 0
    runs: int = 0
    episodes: int = 0
    checked: int = 0  # runs compared with robobpp's own functions
    generate_cpu_s: float = 0.0  # this thread's CPU generating rows
    write_wait_s: float = 0.0  # wall time the generator waited for the writer
    write_s: float = 0.0  # wall time the writer wrote (PostgreSQL: COPY and commit, in its thread)
    database_cpu_s: float | None = None  # the PostgreSQL backend's CPU while seeding (when local)
    cpu_s: float = 0.0  # this process's CPU (generator and writer threads)
    wall_s: float = 0.0

    @property
    def rows(self) -> int:
        return self.submissions + self.runs + self.episodes


@dataclass
class _Run:
    sub: int  # index in the chunk
    submission_id: int
    dataset: str
    setting: str
    protocol: str
    run_id: int = 0
    metrics: dict[str, Any] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)
    figures: dict[str, Any] = field(default_factory=dict)
    entry: bytes = b""
    # per-group figures (GROUPS,) by metric key; counters of Execution
    values: dict[str, np.ndarray] = field(default_factory=dict)
    collapsed: np.ndarray | None = None
    dangerous: np.ndarray | None = None


@dataclass
class _Chunk:
    subs: list[tuple[Any, ...]]
    runs: list[_Run]
    episodes: list[str]  # COPY text lines (PostgreSQL) — or rows (SQLite)
    episode_count: int


def seed(
    runtime: Any,
    n: int,
    *,
    first: int = 0,
    fixed_quality: float | None = None,
    episodes_every: int = 1,
    progress: bool | None = None,
    check: bool = True,
    newest: int = NEWEST_WITH_EPISODES,
) -> Stats:
    """Insert ``n`` finished submissions (the ``first``-th to the ``first + n - 1``-th: ``first`` is how many
    the database already has), finishing now; ``fixed_quality``: theirs (default: drawn per submission)."""
    out = Stats()
    t0, cpu0 = time.perf_counter(), time.process_time()
    engine = runtime.engine
    postgres = engine.dialect.name == "postgresql"
    if first == 0:
        with runtime.session() as s:
            s.add_all([Participant(name=f"team-{i:03d}") for i in range(TEAMS)])
    with runtime.session() as s:
        teams = [
            p for (p,) in s.execute(text("SELECT id FROM participants WHERE name LIKE 'team-%' ORDER BY id"))
        ]
        sub_id = s.execute(text("SELECT coalesce(max(id), 0) FROM submissions")).scalar_one()
        run_id = s.execute(text("SELECT coalesce(max(id), 0) FROM runs")).scalar_one()
        episode_id = s.execute(text("SELECT coalesce(max(id), 0) FROM episodes")).scalar_one()
    now = utcnow()
    ids = _Ids(sub_id, run_id, episode_id)
    writer = _PostgresWriter(engine, out) if postgres else _SqliteWriter(engine, out)
    show = n >= 1000 if progress is None else progress
    bar = _progress(show, n)
    try:
        for lo in range(first, first + n, CHUNK):
            hi = min(lo + CHUNK, first + n)
            c0 = time.thread_time()
            chunk = _generate(
                lo,
                hi,
                first + n,
                now,
                teams,
                ids,
                fixed_quality,
                episodes_every,
                newest,
                postgres,
                check,
                out,
            )
            out.generate_cpu_s += time.thread_time() - c0
            w0 = time.perf_counter()
            writer.put(chunk)
            out.write_wait_s += time.perf_counter() - w0
            out.submissions += len(chunk.subs)
            out.runs += len(chunk.runs)
            out.episodes += chunk.episode_count
            bar(hi - lo, out, time.perf_counter() - t0)
    finally:
        writer.close()
        bar(None, out, time.perf_counter() - t0)
    if postgres:
        with engine.begin() as c:
            for table in ("submissions", "runs", "episodes"):
                c.execute(
                    text(
                        f"SELECT setval(pg_get_serial_sequence('{table}', 'id'), "
                        f"(SELECT coalesce(max(id), 1) FROM {table}))"
                    )
                )
        if n >= 1000:
            with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as c:
                c.execute(text("ANALYZE submissions, runs, episodes"))
    out.wall_s, out.cpu_s = time.perf_counter() - t0, time.process_time() - cpu0
    return out


@dataclass
class _Ids:
    submission: int
    run: int
    episode: int


def _generate(
    lo: int,
    hi: int,
    end: int,
    now: datetime,
    teams: list[int],
    ids: _Ids,
    fixed_quality: float | None,
    episodes_every: int,
    newest: int,
    postgres: bool,
    check: bool,
    out: Stats,
) -> _Chunk:
    rng = np.random.default_rng([SEED, lo])
    quality = rng.random(hi - lo) if fixed_quality is None else np.full(hi - lo, float(fixed_quality))
    subs: list[tuple[Any, ...]] = []
    runs: list[_Run] = []
    for k, i in enumerate(range(lo, hi)):
        kind = kind_of(i)
        settings = ["math"] if kind == "partial" else list(SETTINGS)
        # the server's runs: every setting closed loop, and the physical ones again under the paper protocol
        boards = [(st, "closed") for st in settings] + [
            (st, "paper") for st in paper_settings(settings, "private")
        ]
        ids.submission += 1
        subs.append(
            (
                ids.submission,
                teams[i % TEAMS],
                f"policy-{i}",
                "https://example.org",
                "private",
                "push",
                list(DATASETS),
                settings,
                0,
                "failed" if kind == "failed" else "completed",
                GROUPS * len(DATASETS) * len(boards),
                now - timedelta(days=1),
                now - timedelta(seconds=end - i),
                FAILED_ERROR if kind == "failed" else None,
            )
        )
        for d in DATASETS:
            for st, protocol in boards:
                ids.run += 1
                runs.append(_Run(k, ids.submission, d, st, protocol, ids.run))
    for st in SETTINGS:
        mine = [r for r in runs if r.setting == st]
        if mine:
            _figures(rng, st, mine, quality, [kind_of(lo + r.sub) for r in mine])
            if check:
                _check(mine[len(mine) // 2], [kind_of(lo + r.sub) for r in mine][len(mine) // 2])
                out.checked += 1
    episodes: list[Any] = []
    count = 0
    stamp = now.isoformat()
    for r in runs:
        i = lo + r.sub
        if not (i % episodes_every == 0 or i >= end - newest):
            continue
        term = "policy_error" if kind_of(i) == "failed" else "completed"
        pv = "\\N" if r.setting == "math" else PHYSICS_VERSION
        keys = list(r.values)
        columns = [r.values[k].tolist() for k in keys]
        first_id = ids.episode + 1
        ids.episode += GROUPS
        count += GROUPS
        metrics = "{" + ", ".join(f'"{k}": %r' for k in keys) + "}"
        counters = "{}"
        if r.collapsed is not None and r.dangerous is not None:
            columns += [r.collapsed.tolist(), r.dangerous.tolist()]
            counters = (
                f'{{"placements_attempted": {PLACED}, "placements_collapsed": %d, '
                f'"operations": {PLACED}, "operations_dangerous": %d}}'
            )
        rows = zip(range(first_id, first_id + GROUPS), range(GROUPS), *columns, strict=True)
        if postgres:  # one line of COPY text per episode, from a template (JSON: floats as repr writes them)
            line = (
                f"%d\t{r.submission_id}\t{r.run_id}\t{r.dataset}\t{r.setting}\ttest\t%d\tdone\t1\t{PLACED}\t"
                f"{term}\t\t{BOXES}\t{PLACED}\t{metrics}\t{counters}\t{stamp}\t{pv}\t{r.protocol}\n"
            )
            episodes.extend(line % row for row in rows)
            continue
        for row in rows:
            m = dict(zip(keys, row[2 : 2 + len(keys)], strict=True))
            c = json.loads(counters % tuple(row[2 + len(keys) :]))
            episodes.append(
                {
                    "id": row[0],
                    "submission_id": r.submission_id,
                    "run_id": r.run_id,
                    "dataset": r.dataset,
                    "setting": r.setting,
                    "split": "test",
                    "group": row[1],
                    "status": "done",
                    "attempts": 1,
                    "step": PLACED,
                    "termination": term,
                    "termination_detail": "",
                    "boxes_total": BOXES,
                    "boxes_placed": PLACED,
                    "metrics": m,
                    "counters": c,
                    "finished_at": now,
                    "physics_version": None if r.setting == "math" else PHYSICS_VERSION,
                    "protocol": r.protocol,
                }
            )
    return _Chunk(subs, runs, episodes, count)


def _figures(
    rng: np.random.Generator, setting: str, runs: list[_Run], quality: np.ndarray, kinds: list[str]
) -> None:
    """Draw the episodes' figures of ``runs`` (all of ``setting``) and compute what each run stores."""
    n = len(runs)
    q = quality[[r.sub for r in runs]][:, None]
    shape = (n, GROUPS)
    u = np.clip(0.45 + 0.3 * q + 0.08 * rng.standard_normal(shape), 0.0, 1.0).round(5)
    values = {
        "space_utilization": u,
        "occupancy": np.minimum(1.0, u + 0.2 + 0.1 * rng.random(shape)).round(5),
        "decision_time": (0.001 + rng.random(shape) * 0.01 * (2 - q)).round(6),
    }
    if setting != "math":
        values["local_stability"] = (rng.random(shape) * 0.01).round(6)
        values["static_stability"] = (0.8 + 0.2 * rng.random(shape)).round(5)
    collapsed = dangerous = None
    if setting == "execution":
        values["trajectory_length"] = (3 + 2 * rng.random(shape)).round(4)
        collapsed = rng.integers(0, 4, shape).astype(np.float64)
        dangerous = rng.integers(0, 3, shape).astype(np.float64)
    keys = metric_keys(setting)
    top = np.zeros((n, GROUPS, len(keys)))
    bottom = np.ones((n, GROUPS, len(keys)))
    for j, key in enumerate(keys):
        if key == "collapsed_placement":
            assert collapsed is not None
            top[:, :, j], bottom[:, :, j] = collapsed, PLACED
        elif key == "dangerous_operation":
            assert dangerous is not None
            top[:, :, j], bottom[:, :, j] = dangerous, PLACED
        else:
            top[:, :, j] = values[key]
    # the run's part: robobpp's own functions on the stacked runs (entries.entry_part, one run at a time)
    top, bottom = top.astype(np.float32), bottom.astype(np.float32)
    samples = samples_of(top, bottom, counts(GROUPS))  # (metrics, runs, resamples)
    m = len(keys)
    lo, hi = stats.interval(samples.transpose(2, 1, 0).reshape(samples.shape[2], n * m))
    metric_ci = np.stack([lo.reshape(n, m), hi.reshape(n, m)], axis=2)
    seeds = [part_seed(top[x], bottom[x], setting) for x in range(n)]
    slo, shi = stats.interval(stable_samples(with_timing_noise(samples, seeds, setting), setting).T)
    # means as the worker takes them: a sequential sum (Python's ``sum``) over the count
    means = {k: np.cumsum(v, axis=1)[:, -1] / GROUPS for k, v in values.items()}
    pooled_sum = (
        {
            "collapsed_placement": np.cumsum(collapsed, axis=1)[:, -1] / (PLACED * GROUPS),
            "dangerous_operation": np.cumsum(dangerous, axis=1)[:, -1] / (PLACED * GROUPS),
        }
        if collapsed is not None and dangerous is not None
        else {}
    )
    pooled_counts = (
        {"collapsed_placement": collapsed, "dangerous_operation": dangerous}
        if collapsed is not None and dangerous is not None
        else {}
    )
    group_ids = np.arange(GROUPS, dtype=np.int64)
    listed = {k: v.tolist() for k, v in values.items()}
    mean_lists = {k: v.tolist() for k, v in (means | pooled_sum).items()}
    order = [m.key for m in metrics_for(setting)]
    for x, r in enumerate(runs):
        r.values = {k: v[x] for k, v in values.items()}
        if collapsed is not None and dangerous is not None:
            r.collapsed, r.dangerous = collapsed[x].astype(np.int64), dangerous[x].astype(np.int64)
        r.metrics = {k: mean_lists[k][x] for k in order}
        term = "policy_error" if kinds[x] == "failed" else "completed"
        r.extras = {
            "episodes": GROUPS,
            "boxes_placed_mean": float(PLACED),
            "episodes_collapsed": 0,
            "terminations": {term: GROUPS},
            "provenance": recorded_rules(),  # as a worker records it: the boards show only current rules
        }
        if setting == "execution":
            dt, traj = r.metrics["decision_time"], r.metrics["trajectory_length"]
            r.extras["pph"] = 3600.0 / (dt + traj / 0.34 + 2.0)
        r.figures = {
            "ids": list(range(GROUPS)),
            "values": {k: listed[k][x] for k in order if k not in POOLED},
            "pooled": {
                k: [[float(a), float(PLACED)] for a in pooled_counts[k][x]] for k in order if k in POOLED
            },
        }
        r.entry = EntryPart(
            setting,
            group_ids,
            top[x],
            bottom[x],
            metric_ci[x],
            (float(slo[x]), float(shi[x])),
            seeds[x],
        ).encode()


def _check(r: _Run, kind: str) -> None:
    """The run's stored figures are what the worker computes from its episodes (robobpp's own functions)."""
    term = "policy_error" if kind == "failed" else "completed"
    rows = []
    episodes = []
    for g in range(GROUPS):
        m = {k: float(v[g]) for k, v in r.values.items()}
        c: dict[str, int] = {}
        if r.collapsed is not None and r.dangerous is not None:
            c = {
                "placements_attempted": PLACED,
                "placements_collapsed": int(r.collapsed[g]),
                "operations": PLACED,
                "operations_dangerous": int(r.dangerous[g]),
            }
        rows.append((m, c, term, PLACED))
        episodes.append({**m, **c, "group": g})
    metrics, extras = run_figures(rows, r.setting)
    extras["provenance"] = recorded_rules()  # what finalize_run adds from the episodes' provenance
    figures = group_figures(episodes, r.setting)
    entry = part_of_run(figures, r.setting)
    for label, mine, theirs in (
        ("metrics", r.metrics, metrics),
        ("extras", r.extras, extras),
        ("figures", r.figures, figures),
        ("entry", r.entry, entry),
    ):
        if mine != theirs:
            raise AssertionError(f"{r.setting} run {r.run_id}: its {label} differ from what a worker stores")


class _PostgresWriter:
    """``COPY`` of each chunk in a thread of its own (one connection, one transaction per chunk)."""

    def __init__(self, engine: Any, stats: Stats) -> None:
        self.stats = stats
        self.raw = engine.raw_connection()
        with self.raw.cursor() as cur:
            cur.execute("SET session_replication_role = replica")  # no foreign-key triggers
            cur.execute("SET synchronous_commit = off")
            cur.execute("SELECT pg_backend_pid()")
            self.backend = int(cur.fetchone()[0])
        self.raw.commit()
        self.cpu0 = _process_cpu(self.backend)
        self.jobs: queue.Queue[_Chunk | None] = queue.Queue(maxsize=1)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def put(self, chunk: _Chunk) -> None:
        if self.error is not None:
            raise RuntimeError("writing failed") from self.error
        self.jobs.put(chunk)

    def close(self) -> None:
        self.jobs.put(None)
        self.thread.join()
        cpu = _process_cpu(self.backend)
        if cpu is not None and self.cpu0 is not None:
            self.stats.database_cpu_s = cpu - self.cpu0
        try:
            with self.raw.cursor() as cur:
                cur.execute("SET session_replication_role = origin")
            self.raw.commit()
        finally:
            self.raw.close()
        if self.error is not None:
            raise RuntimeError("writing failed") from self.error

    def _run(self) -> None:
        while (chunk := self.jobs.get()) is not None:
            if self.error is not None:
                continue
            try:
                self._write(chunk)
            except BaseException as e:  # noqa: BLE001 - reported by put/close, whatever it was
                self.error = e
                self.raw.rollback()

    def _write(self, chunk: _Chunk) -> None:
        t0 = time.perf_counter()
        with self.raw.cursor() as cur:
            _copy(cur, "submissions", SUBMISSION_COLUMNS, _lines(chunk.subs))
            _copy(cur, "runs", RUN_COLUMNS, _run_lines(chunk.runs))
            if chunk.episodes:
                _copy(cur, "episodes", EPISODE_COLUMNS, iter(("".join(chunk.episodes),)))
        self.raw.commit()
        self.stats.write_s += time.perf_counter() - t0


def _process_cpu(pid: int) -> float | None:
    """User + system CPU seconds of a local process (Linux), or None (another host)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def _copy(cur: Any, table: str, columns: tuple[str, ...], data: Iterator[str]) -> None:
    quoted = ", ".join(f'"{c}"' for c in columns)  # "group" is an SQL keyword
    with cur.copy(f"COPY {table} ({quoted}) FROM STDIN") as copy:
        buf = io.StringIO()
        for line in data:
            buf.write(line)
        copy.write(buf.getvalue())


def _field(v: Any) -> str:
    if v is None:
        return "\\N"
    if isinstance(v, datetime):
        return v.isoformat()
    if isinstance(v, bytes):
        return "\\\\x" + v.hex()
    if isinstance(v, list | dict):
        v = json.dumps(v)
    return str(v).replace("\\", "\\\\").replace("\t", "\\t").replace("\n", "\\n")


def _lines(rows: list[tuple[Any, ...]]) -> Iterator[str]:
    for row in rows:
        yield "\t".join(_field(v) for v in row) + "\n"


def _run_values(r: _Run, completed: datetime | None = None) -> tuple[Any, ...]:
    return (
        r.run_id,
        r.submission_id,
        r.dataset,
        r.setting,
        r.protocol,
        "completed",
        GROUPS,
        r.metrics,
        r.extras,
        r.figures,
        r.entry,
        completed,
    )


def _run_lines(runs: list[_Run]) -> Iterator[str]:
    now = utcnow()
    return _lines([_run_values(r, now) for r in runs])


class _SqliteWriter:
    """One ``executemany`` per table and chunk, in this thread."""

    def __init__(self, engine: Any, stats: Stats) -> None:
        self.engine = engine
        self.stats = stats

    def put(self, chunk: _Chunk) -> None:
        t0 = time.perf_counter()
        now = utcnow()
        with self.engine.begin() as c:
            c.execute(insert(Submission), [dict(zip(SUBMISSION_COLUMNS, s, strict=True)) for s in chunk.subs])
            c.execute(
                insert(RunRow), [dict(zip(RUN_COLUMNS, _run_values(r, now), strict=True)) for r in chunk.runs]
            )
            if chunk.episodes:
                c.execute(insert(EpisodeRow), chunk.episodes)
        self.stats.write_s += time.perf_counter() - t0

    def close(self) -> None:
        pass


def _progress(show: bool, total: int) -> Callable[[int | None, Stats, float], None]:
    """A rich progress bar (submissions, rows per second) when ``show``; ``None`` as the step ends it. Not
    on a terminal (a log file), one line per tenth of the work instead."""
    if not show:
        return lambda _step, _stats, _elapsed: None
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    console = Console(stderr=True)
    done, printed = 0, 0

    if not console.is_terminal:

        def line(n: int | None, s: Stats, elapsed: float) -> None:
            nonlocal done, printed
            if n is None and printed == 10:  # the last step said it all
                return
            done += n or 0
            if n is not None and done < total and done * 10 // total == printed:
                return
            printed = done * 10 // total
            console.print(
                f"seeding: {done:,}/{total:,} submissions, {s.rows:,} rows in {elapsed:.0f} s "
                f"({s.rows / max(elapsed, 1e-9):,.0f} rows/s)",
                highlight=False,
            )

        return line

    bar = Progress(
        TextColumn("seeding"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"),
        TimeRemainingColumn(),
        console=console,
    )
    task = bar.add_task("seed", total=total, rate="")
    bar.start()

    def step(n: int | None, s: Stats, elapsed: float) -> None:
        if n is None:
            bar.stop()
            return
        bar.update(task, advance=n, rate=f"{s.rows / max(elapsed, 1e-9):,.0f} rows/s")

    return step
