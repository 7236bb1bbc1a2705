"""``robobpp compare``: score local results against each other exactly as the leaderboard does.

Each ``robobpp evaluate --json FILE`` run is an entry; entries are compared board by board (dataset ×
setting) with the min–max weighted scoring of BENCHMARK.md §5, only where they ran the same episodes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from robobpp.cli.common import fail, table_console
from robobpp.metrics import metrics_for
from robobpp.scoring import score_entries


def register(root: typer.Typer) -> None:
    root.command("compare")(compare)


def load_entries(paths: list[Path]) -> list[dict[str, Any]]:
    """One entry per (file, board): policy name, board, metrics and the episode ids it ran."""
    entries: list[dict[str, Any]] = []
    for path in paths:
        try:
            payload = json.loads(path.read_text())
            episodes = payload["episodes"]
            for run in payload["runs"]:
                ids = sorted(
                    e["episode_id"]
                    for e in episodes
                    if e["dataset"] == run["dataset"] and e["setting"] == run["setting"]
                )
                entries.append({"policy": str(payload["policy"]), "file": str(path), "dataset": run["dataset"],
                                "setting": run["setting"], "metrics": dict(run["metrics"]), "episodes": ids})  # fmt: skip
        except OSError as exc:
            fail(f"{path}: cannot read ({exc.strerror})")
        except (ValueError, KeyError, TypeError) as exc:
            fail(f"{path}: not a `robobpp evaluate --json` file ({type(exc).__name__}: {exc})")
    return entries


def score_boards(entries: list[dict[str, Any]]) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """Scored entries per board, best first. Entries of one board must have run the same episodes."""
    boards: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for entry in entries:
        boards.setdefault((entry["dataset"], entry["setting"]), []).append(entry)
    for (dataset, setting), rows in boards.items():
        reference = rows[0]
        for row in rows[1:]:
            if row["episodes"] != reference["episodes"]:
                fail(f"{dataset}/{setting}: {row['file']} and {reference['file']} ran different episodes "
                     "(use the same --split, --seed and --groups)")  # fmt: skip
        for row, scored in zip(rows, score_entries([r["metrics"] for r in rows], setting), strict=True):
            row.update(score=scored.score, rank=scored.rank, normalized=scored.normalized)
        rows.sort(key=lambda r: (r["rank"], r["policy"]))
    return boards


def compare(
    results: Annotated[list[Path], typer.Argument(help="Files written by `robobpp evaluate --json`.")],
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the scored boards here.")] = None,
) -> None:
    """Rank local evaluation results board by board with the leaderboard's scoring."""
    if len(results) < 2:
        fail("give at least two result files: scores are relative to the other entries")
    boards = score_boards(load_entries(results))
    out = table_console()
    for (dataset, setting), rows in boards.items():
        table = Table(title=f"{dataset} · {setting}")
        table.add_column("rank", justify="right")
        table.add_column("policy")
        table.add_column("score ↑", justify="right")
        keys = metrics_for(setting)
        for m in keys:
            table.add_column(f"{m.label} {'↑' if m.better == 'up' else '↓'}", justify="right")
        for row in rows:
            values = [row["metrics"].get(m.key) for m in keys]
            table.add_row(str(row["rank"]), escape(row["policy"]), f"{row['score']:.3f}",
                          *("—" if v is None else f"{v:.4f}" for v in values))  # fmt: skip
        out.print(table)
    if json_out is not None:
        payload = [{"dataset": d, "setting": s, "entries": rows} for (d, s), rows in boards.items()]
        json_out.write_text(json.dumps(payload, indent=1, allow_nan=False))
