"""``robobpp compare``: score local results against each other exactly as the leaderboard does.

Each ``robobpp evaluate --json FILE`` run is an entry; entries are compared board by board (dataset ×
setting) with the leaderboard's scoring (docs/benchmark.md, "Scoring and uncertainty"), only where they ran the same episodes. Every
figure carries its bootstrap 95 % interval over groups, every rank its rank interval; with two files the
paired difference A − B of each metric and of the stable score is shown with its interval and a verdict.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from robobpp.cli.common import fail, table_console
from robobpp.provenance import merged
from robobpp.scoring import stats
from robobpp.scoring.metrics import METRIC_BY_KEY, metrics_for
from robobpp.scoring.scores import score_board
from robobpp.vocabulary import CLOSED


def register(root: typer.Typer) -> None:
    root.command("compare")(compare)


#: Per-episode version fields a comparison checks (``EpisodeResult``), by provenance name.
VERSIONED = {"physics": "physics_version", "math_rules": "rules_version", "sampler": "sampler_version"}


def load_entries(paths: list[Path]) -> list[dict[str, Any]]:
    """One entry per (file, board): policy name, board, metrics, per-group figures and the episode ids."""
    entries: list[dict[str, Any]] = []
    for path in paths:
        try:
            payload = json.loads(path.read_text())
            episodes = payload["episodes"]
            for run in payload["runs"]:
                # closed loop and the paper protocol are different boards (files from before protocols: closed)
                protocol = str(run.get("protocol", CLOSED))
                mine = [
                    e
                    for e in episodes
                    if e["dataset"] == run["dataset"]
                    and e["setting"] == run["setting"]
                    and e.get("protocol", CLOSED) == protocol
                ]
                figures = stats.group_figures(
                    (
                        {**(e.get("metrics") or {}), **(e.get("counters") or {}), "group": e["group"]}
                        for e in mine
                    ),
                    run["setting"],
                )
                # what the episodes ran under (files from before versions: unknown, not checked)
                versions = {key: merged(e.get(field) for e in mine) for key, field in VERSIONED.items()}
                entries.append(
                    {
                        "policy": str(payload["policy"]),
                        "file": str(path),
                        "dataset": run["dataset"],
                        "setting": run["setting"],
                        "protocol": protocol,
                        "metrics": dict(run["metrics"]),
                        "figures": figures,
                        "episodes": sorted(e["episode_id"] for e in mine),
                        "versions": versions,
                        # next boxes the policy saw (files from before it was recorded: 0, the default)
                        "lookahead": int((payload.get("provenance") or {}).get("lookahead") or 0),
                        "provenance": payload.get("provenance"),
                    }
                )
        except OSError as exc:
            fail(f"{path}: cannot read ({exc.strerror})")
        except (ValueError, KeyError, TypeError) as exc:
            fail(f"{path}: not a `robobpp evaluate --json` file ({type(exc).__name__}: {exc})")
    return entries


def score_boards(entries: list[dict[str, Any]]) -> dict[tuple[str, str, str], list[dict[str, Any]]]:
    """Scored entries per board (dataset, setting, protocol), best first, with intervals. Entries of a board
    must have run the same episodes."""
    boards: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for entry in entries:
        boards.setdefault((entry["dataset"], entry["setting"], entry["protocol"]), []).append(entry)
    for (dataset, setting, _protocol), rows in boards.items():
        reference = rows[0]
        for row in rows[1:]:
            if row["episodes"] != reference["episodes"]:
                fail(
                    f"{dataset}/{setting}: {row['file']} and {reference['file']} ran different episodes "
                    "(use the same --split, --seed and --groups)"
                )
            if row["lookahead"] != reference["lookahead"]:  # nor lookaheads (docs/benchmark.md)
                fail(
                    f"{dataset}/{setting}: {row['file']} saw {row['lookahead']} next boxes (--lookahead), "
                    f"{reference['file']} {reference['lookahead']}: not comparable; the leaderboard ranks "
                    "each lookahead on boards of its own"
                )
            for key, mine in row["versions"].items():  # a board never mixes versions (docs/benchmark.md)
                theirs = reference["versions"].get(key)
                if mine is not None and theirs is not None and mine != theirs:
                    fail(
                        f"{dataset}/{setting}: {row['file']} ran {key} version {mine}, {reference['file']} "
                        f"version {theirs}: not comparable; evaluate both with one robobpp"
                    )
        scores = score_board(rows, setting)
        for i, row in enumerate(rows):
            s = scores.scored[i]
            row.update(
                score=s.score,
                rank=s.rank,
                normalized=s.normalized,
                score_ci=list(scores.score_ci[i]),
                rank_ci=None if (rank_ci := scores.rank_ci[i]) is None else list(rank_ci),
                stable=scores.stable[i],
                stable_ci=list(scores.stable_ci[i]),
                intervals={k: list(v) if v else None for k, v in scores.metric_ci[i].items()},
            )
        if len(rows) == 2:
            diff = scores.stable_samples[:, 0].astype(np.float64) - scores.stable_samples[:, 1]
            lo, hi = stats.interval(diff[:, None])
            paired = {
                "stable": {
                    "difference": scores.stable[0] - scores.stable[1],
                    "low": float(lo[0]),
                    "high": float(hi[0]),
                    "groups": len(rows[0]["figures"]["ids"]),
                }
            }
            for m in metrics_for(setting):
                paired[m.key] = stats.paired_difference(rows[0]["figures"], rows[1]["figures"], m.key)
            for row in rows:
                row["paired"] = {"a": rows[0]["policy"], "b": rows[1]["policy"], "differences": paired}
        rows.sort(key=lambda r: (r["rank"], r["policy"]))
    return boards


def verdict(a: str, b: str, key: str, d: dict[str, Any]) -> str:
    """Plain words for one paired difference A − B with its interval."""
    if d["difference"] is None or d["low"] is None:
        return "not measured"
    better = "up" if key == "stable" else METRIC_BY_KEY[key].better
    if d["low"] <= 0.0 <= d["high"]:
        return f"no clear difference over {d['groups']} groups (the interval contains 0)"
    a_ahead = (d["low"] > 0) == (better == "up")
    return f"{a if a_ahead else b} is better (the whole interval is on its side)"


def compare(
    results: Annotated[list[Path], typer.Argument(help="Files written by `robobpp evaluate --json`.")],
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the scored boards here.")] = None,
) -> None:
    """Rank local evaluation results board by board with the leaderboard's scoring, with intervals."""
    if len(results) < 2:
        fail("give at least two result files: scores are relative to the other entries")
    boards = score_boards(load_entries(results))
    out = table_console()
    for (dataset, setting, protocol), rows in boards.items():
        board = f"{dataset} · {setting}" + (f" · protocol {protocol}" if protocol != CLOSED else "")
        table = Table(title=board, caption="[dim]brackets: bootstrap 95 % interval over groups[/]")
        table.add_column("rank", justify="right")
        table.add_column("policy")
        table.add_column("score ↑", justify="right")
        table.add_column("stable ↑", justify="right")
        keys = metrics_for(setting)
        for m in keys:
            table.add_column(f"{m.label} {'↑' if m.better == 'up' else '↓'}", justify="right")
        for row in rows:
            lo, hi = row["rank_ci"]
            rank = str(row["rank"]) if lo == hi else f"{row['rank']} ({lo}–{hi})"
            cells = []
            for m in keys:
                value, ci = row["metrics"].get(m.key), row["intervals"].get(m.key)
                cells.append(
                    "—"
                    if value is None
                    else f"{value:.4f}" + (f" [dim][{ci[0]:.4f}, {ci[1]:.4f}][/]" if ci else "")
                )
            table.add_row(
                rank,
                escape(row["policy"]),
                _with_ci(row["score"], row["score_ci"]),
                _with_ci(row["stable"], row["stable_ci"]),
                *cells,
            )
        out.print(table)
        paired = rows[0].get("paired")
        if paired:
            a, b = paired["a"], paired["b"]
            diff = Table(title=f"{board}: paired difference {escape(a)} − {escape(b)} on the same groups")
            for name in ("figure", "difference", "95 % interval", "verdict"):
                diff.add_column(name, justify="left" if name in ("figure", "verdict") else "right")
            for key, d in paired["differences"].items():
                label = "Stable score" if key == "stable" else METRIC_BY_KEY[key].label
                diff.add_row(
                    label,
                    "—" if d["difference"] is None else f"{d['difference']:+.4f}",
                    "—" if d["low"] is None else f"[{d['low']:+.4f}, {d['high']:+.4f}]",
                    escape(verdict(a, b, key, d)),
                )
            out.print(diff)
    if json_out is not None:
        payload = [
            {"dataset": d, "setting": s, "protocol": p, "entries": rows} for (d, s, p), rows in boards.items()
        ]
        json_out.write_text(json.dumps(payload, indent=1, allow_nan=False))


def _with_ci(value: float, ci: list[float]) -> str:
    return f"{value:.3f} [dim][{ci[0]:.3f}, {ci[1]:.3f}][/]"
