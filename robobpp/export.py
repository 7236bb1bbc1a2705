"""Results as files for papers and spreadsheets: per-group CSV, summary tables in Markdown and LaTeX.

Two sources, one layout: a local run (the payload ``robobpp evaluate --json`` writes) and a board (the API's
``Leaderboard``, as a dict). Every figure keeps its 95 % bootstrap interval over groups and every file its
provenance (robobpp/provenance.py): a table's note names the versions, protocol, split, seed and groups it
was made with; the CSVs carry them in columns.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from robobpp.provenance import FIELDS, merge, one_line
from robobpp.scoring.metrics import METRIC_BY_KEY, METRICS, metrics_for

FORMATS = ("csv", "md", "latex")


@dataclass(slots=True)
class Sheet:
    """A table: a title, column headers, rows of text cells and a note (provenance, interval method)."""

    title: str
    headers: list[str]
    rows: list[list[str]] = field(default_factory=list)
    note: str = ""


#: Decimals of every figure in a board's or the grid's CSV: the precision scores and ranks are computed at
#: (robobpp/scoring.py rounds to 12 so that ties tie), so a Mean is not printed to 16 digits beside them.
SUMMARY_DECIMALS = 12


def _cell(value: Any, decimals: int | None = None) -> str:
    """A CSV cell: a float in full (per-group measurements) or rounded to ``decimals`` (summary figures)."""
    if value is None:
        return ""
    if isinstance(value, list):
        return ",".join(map(str, value))
    if isinstance(value, float):
        return repr(value if decimals is None else round(value, decimals) + 0.0)  # + 0.0: no "-0.0"
    return str(value)


def _figure(value: float | None, interval: Sequence[float] | None, digits: int = 4) -> str:
    if value is None:
        return "—"
    text = f"{value:.{digits}f}"
    return text + (f" [{interval[0]:.{digits}f}, {interval[1]:.{digits}f}]" if interval else "")


def _label(key: str) -> str:
    m = METRIC_BY_KEY[key]
    return f"{m.label} {'↑' if m.better == 'up' else '↓'}" + (f" ({m.unit})" if m.unit else "")


# -- a local run ------------------------------------------------------------------------------------------
def group_csv(payload: Mapping[str, Any]) -> str:
    """One row per group (episode) of a ``robobpp evaluate --json`` payload: what it ran, how it ended, its
    metrics, and the provenance (the episode's own versions, the run's installation and data)."""
    episodes = payload.get("episodes") or []
    settings = {e["setting"] for e in episodes}
    keys = [m.key for m in METRICS if any(s in m.settings for s in settings)]
    run = payload.get("provenance") or {}
    head = [
        "policy",
        "dataset",
        "setting",
        "protocol",
        "lookahead",
        "split",
        "group",
        "episode_id",
        "group_seed",
        "termination",
        "boxes_placed",
        "boxes_total",
        *keys,
        "physics",
        "math_rules",
        "sampler",
        "robobpp",
        "commit",
        "datasets_manifest_sha256",
        "anchors",
        "seed",
        "groups",
    ]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(head)
    for e in sorted(episodes, key=lambda e: (e["dataset"], e["setting"], e.get("protocol", ""), e["group"])):
        metrics = e.get("metrics") or {}
        writer.writerow(
            [
                _cell(v)
                for v in (
                    payload.get("policy"),
                    e["dataset"],
                    e["setting"],
                    e.get("protocol", "closed"),
                    run.get("lookahead"),
                    e["split"],
                    e["group"],
                    e["episode_id"],
                    e.get("seed"),
                    e["termination"],
                    e["boxes_placed"],
                    e["boxes_total"],
                    *(metrics.get(k) for k in keys),
                    e.get("physics_version"),
                    e.get("rules_version"),
                    e.get("sampler_version"),
                    run.get("robobpp"),
                    run.get("commit"),
                    run.get("datasets_manifest_sha256"),
                    run.get("anchors"),
                    payload.get("seed"),
                    payload.get("groups"),
                )
            ]
        )
    return out.getvalue()


def run_sheet(payload: Mapping[str, Any]) -> Sheet:
    """The summary of a local run: each (dataset, setting) with its figures and intervals."""
    runs = payload.get("runs") or []
    keys = [m.key for m in METRICS if any(m.key in (r.get("metrics") or {}) for r in runs)]
    sheet = Sheet(
        f"robobpp evaluate · {payload.get('policy')}",
        ["dataset", "setting", "episodes", *(_label(k) for k in keys), "stable score ↑"],
    )
    for r in runs:
        intervals = r.get("intervals") or {}
        sheet.rows.append(
            [
                r["dataset"],
                r["setting"],
                str(r["episodes"]),
                *(_figure((r.get("metrics") or {}).get(k), intervals.get(k)) for k in keys),
                _figure(r.get("stable"), r.get("stable_interval"), 3),
            ]
        )
    confidence = float(payload.get("confidence") or 0.95)
    sheet.note = f"Brackets: bootstrap {100 * confidence:.0f} % interval over groups. " + one_line(
        payload.get("provenance") or {}
    )
    return sheet


# -- a board ----------------------------------------------------------------------------------------------
SPLIT_OF_TRACK = {"private": "test", "public": "train"}


def board_provenance(board: Mapping[str, Any]) -> dict[str, Any]:
    """What produced a board's entries (their runs' provenance, merged) and how the board was drawn."""
    rows = [(e.get("extras") or {}).get("provenance") or {} for e in board.get("entries") or []]
    produced = {k: v for k, v in merge(rows).items() if k in FIELDS}
    return {
        **produced,
        "anchors": board.get("anchors"),
        "protocol": board.get("protocol", "closed"),
        "lookahead": board.get("lookahead", 0),
        "split": SPLIT_OF_TRACK.get(str(board.get("track")), board.get("track")),
        "groups": board.get("groups"),
    }


#: Provenance fields a board's CSV writes once per board, not from each entry's runs (every entry of a board
#: shares them: a board never mixes protocols nor lookaheads).
_BOARD_WIDE = ("anchors", "protocol", "lookahead", "split", "groups")


def lookahead_title(lookahead: Any) -> str:
    """What a title adds for a board or grid of lookahead K > 0 (lookahead 0, the leaderboard, goes unsaid)."""
    return f" · lookahead {lookahead}" if lookahead else ""


def board_csv(board: Mapping[str, Any]) -> str:
    """One row per ranked entry, then the entries listed apart: ranks, scores and metrics with their interval
    ends in their own columns, and each entry's provenance."""
    keys = list(board.get("metrics") or [m.key for m in metrics_for(str(board["setting"]))])
    head = [
        "dataset",
        "setting",
        "track",
        "protocol",
        "lookahead",
        "status",
        "rank",
        "rank_low",
        "rank_high",
        "submission_id",
        "name",
        "participant",
        "baseline",
        "entries_submitted",
        "score",
        "score_low",
        "score_high",
        "stable",
        "stable_low",
        "stable_high",
    ]
    for k in keys:
        head += [k, f"{k}_low", f"{k}_high"]
    head += [f for f in FIELDS if f not in _BOARD_WIDE] + ["anchors", "groups"]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(head)
    common = [
        board["dataset"],
        board["setting"],
        board.get("track"),
        board.get("protocol", "closed"),
        board.get("lookahead", 0),
    ]
    for status, entries in (("ranked", board.get("entries") or []), (None, board.get("unranked") or [])):
        for e in entries:
            intervals = e.get("intervals") or {}
            row = [
                *common,
                status or e.get("status"),
                e.get("rank"),
                e.get("rank_low"),
                e.get("rank_high"),
                e["submission_id"],
                e["name"],
                e["participant"],
                e["baseline"],
                e.get("entries_submitted"),
                e.get("score"),
                e.get("score_low"),
                e.get("score_high"),
                e.get("stable"),
                e.get("stable_low"),
                e.get("stable_high"),
            ]
            for k in keys:
                ci = intervals.get(k) or (None, None)
                row += [(e.get("metrics") or {}).get(k), ci[0], ci[1]]
            prov = (e.get("extras") or {}).get("provenance") or {}
            row += [prov.get(f) for f in FIELDS if f not in _BOARD_WIDE]
            row += [board.get("anchors"), board.get("groups")]
            writer.writerow([_cell(v, SUMMARY_DECIMALS) for v in row])
    return out.getvalue()


def board_sheet(board: Mapping[str, Any]) -> Sheet:
    """A board as a summary table: rank (interval), entry, metrics, both scores with their intervals."""
    keys = list(board.get("metrics") or [])
    protocol = " · paper protocol" if board.get("protocol") == "paper" else ""  # closed loop goes unsaid
    sheet = Sheet(
        f"{board['setting']}/{board['dataset']}{protocol}{lookahead_title(board.get('lookahead'))} · "
        f"{board.get('track')} track",
        ["rank", "entry", *(_label(k) for k in keys), "score ↑", "stable score ↑"],
    )
    for e in board.get("entries") or []:
        lo, hi, rank = e.get("rank_low"), e.get("rank_high"), e.get("rank")
        shown = str(rank) if lo is None or lo == hi == rank else f"{rank} ({lo}–{hi})"
        name = f"{e['name']} ({e['participant']}{', baseline' if e.get('baseline') else ''})"
        intervals = e.get("intervals") or {}
        sheet.rows.append(
            [
                shown,
                name,
                *(_figure((e.get("metrics") or {}).get(k), intervals.get(k)) for k in keys),
                _figure(e.get("score"), (e.get("score_low"), e.get("score_high")), 3),
                _figure(e.get("stable"), (e.get("stable_low"), e.get("stable_high")), 3),
            ]
        )
    confidence = float(board.get("confidence") or 0.95)
    sheet.note = (
        f"Brackets: bootstrap {100 * confidence:.0f} % interval over groups; rank (interval) in "
        f"{100 * confidence:.0f} % of resamples. Ranked by the {board.get('ranked_by', 'relative')} score, "
        "which depends on the other entries; the stable score does not. " + one_line(board_provenance(board))
    )
    return sheet


# -- the overall grid ------------------------------------------------------------------------------------
def _grid_boards(grid: Mapping[str, Any]) -> list[str]:
    return [f"{s}/{d}" for s in grid.get("settings") or [] for d in grid.get("datasets") or []]


def grid_csv(grid: Mapping[str, Any]) -> str:
    """One row per submission of the overall grid (ranked, then apart): the Mean and stable score with their
    intervals, the rank with its interval, and each board's score and rank."""
    boards = _grid_boards(grid)
    head = [
        "track",
        "protocol",
        "lookahead",
        "status",
        "rank",
        "rank_low",
        "rank_high",
        "submission_id",
        "name",
        "participant",
        "baseline",
        "mean",
        "mean_low",
        "mean_high",
        "stable",
        "stable_low",
        "stable_high",
    ]
    for b in boards:
        head += [f"{b}_score", f"{b}_rank"]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(head)
    for r in [*(grid.get("rows") or []), *(grid.get("apart") or [])]:
        row = [
            grid.get("track"),
            grid.get("protocol", "closed"),
            grid.get("lookahead", 0),
            r.get("status"),
            r.get("rank"),
            r.get("rank_low"),
            r.get("rank_high"),
            r["submission_id"],
            r["name"],
            r["participant"],
            r["baseline"],
            r.get("mean"),
            r.get("mean_low"),
            r.get("mean_high"),
            r.get("stable"),
            r.get("stable_low"),
            r.get("stable_high"),
        ]
        for b in boards:
            cell = (r.get("cells") or {}).get(b) or {}
            row += [cell.get("score"), cell.get("rank") or (r.get("unranked") or {}).get(b)]
        writer.writerow([_cell(v, SUMMARY_DECIMALS) for v in row])
    return out.getvalue()


def grid_sheet(grid: Mapping[str, Any]) -> Sheet:
    """The overall grid as the paper's table: each board's score (rank), the Mean with its interval."""
    boards = _grid_boards(grid)
    sheet = Sheet(
        f"overall · {grid.get('track')} track · protocol {grid.get('protocol', 'closed')}"
        f"{lookahead_title(grid.get('lookahead'))}",
        ["rank", "entry", *boards, "mean ↑", "stable score ↑"],
    )
    for r in [*(grid.get("rows") or []), *(grid.get("apart") or [])]:
        lo, hi, rank = r.get("rank_low"), r.get("rank_high"), r.get("rank")
        shown = (
            r.get("status", "")
            if rank is None
            else str(rank)
            if lo is None or lo == hi == rank
            else f"{rank} ({lo}–{hi})"
        )
        cells = []
        for b in boards:
            c = (r.get("cells") or {}).get(b)
            cells.append(f"{c['score']:.3f} ({c['rank']})" if c else (r.get("unranked") or {}).get(b, "—"))
        sheet.rows.append(
            [
                shown,
                f"{r['name']} ({r['participant']}{', baseline' if r.get('baseline') else ''})",
                *cells,
                _figure(r.get("mean"), (r.get("mean_low"), r.get("mean_high")), 3),
                _figure(r.get("stable"), (r.get("stable_low"), r.get("stable_high")), 3),
            ]
        )
    split = SPLIT_OF_TRACK.get(str(grid.get("track")), grid.get("track"))
    sheet.note = (
        f"Each board: relative score (rank). Mean over {grid.get('boards')} boards with its bootstrap 95 % "
        f"interval; rank (interval) in 95 % of resamples; split {split}; lookahead {grid.get('lookahead', 0)}. "
        "Each board's provenance: robobpp leaderboard --dataset D --setting S"
        + (f" --lookahead {grid['lookahead']}" if grid.get("lookahead") else "")
        + " --format csv."
    )
    return sheet


# -- rendering --------------------------------------------------------------------------------------------
def markdown(sheet: Sheet) -> str:
    def esc(text: str) -> str:
        return text.replace("|", "\\|")

    lines = [
        f"**{esc(sheet.title)}**",
        "",
        "| " + " | ".join(map(esc, sheet.headers)) + " |",
        "|" + "|".join("---" if i < 2 else "---:" for i in range(len(sheet.headers))) + "|",
    ]
    lines += ["| " + " | ".join(map(esc, row)) + " |" for row in sheet.rows]
    if sheet.note:
        lines += ["", esc(sheet.note)]
    return "\n".join(lines) + "\n"


_LATEX = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "↑": r"$\uparrow$",
    "↓": r"$\downarrow$",
    "—": "---",
    "–": "--",
    "·": r"$\cdot$",
}


def latex_escape(text: str) -> str:
    return "".join(_LATEX.get(ch, ch) for ch in text)


def latex(sheet: Sheet) -> str:
    """A ``table`` with a ``tabular`` (booktabs rules: ``\\usepackage{booktabs}``) and the note as caption."""
    spec = "ll" + "r" * (len(sheet.headers) - 2)
    lines = [
        r"\begin{table}",
        r"\centering",
        r"\small",
        rf"\begin{{tabular}}{{{spec}}}",
        r"\toprule",
        " & ".join(latex_escape(h) for h in sheet.headers) + r" \\",
        r"\midrule",
    ]
    lines += [" & ".join(latex_escape(c) for c in row) + r" \\" for row in sheet.rows]
    lines += [
        r"\bottomrule",
        r"\end{tabular}",
        rf"\caption{{{latex_escape(sheet.title)}. {latex_escape(sheet.note)}}}",
        r"\end{table}",
    ]
    return "\n".join(lines) + "\n"


def render_run(payload: Mapping[str, Any], fmt: str) -> str:
    """A local run in ``fmt``: ``csv`` (per group), ``md`` or ``latex`` (summary)."""
    if fmt == "csv":
        return group_csv(payload)
    return _render(run_sheet(payload), fmt)


def render_board(board: Mapping[str, Any], fmt: str) -> str:
    """A board in ``fmt``: ``csv`` (per entry), ``md`` or ``latex`` (summary)."""
    if fmt == "csv":
        return board_csv(board)
    return _render(board_sheet(board), fmt)


def render_grid(grid: Mapping[str, Any], fmt: str) -> str:
    """The overall grid in ``fmt``: ``csv`` (per submission), ``md`` or ``latex`` (the paper's table)."""
    if fmt == "csv":
        return grid_csv(grid)
    return _render(grid_sheet(grid), fmt)


def _render(sheet: Sheet, fmt: str) -> str:
    if fmt == "md":
        return markdown(sheet)
    if fmt == "latex":
        return latex(sheet)
    raise ValueError(f"unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
