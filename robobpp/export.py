"""Results as files for papers and spreadsheets: per-group CSV, summary tables in Markdown and LaTeX.

Two sources, one layout: a local run (the payload ``robobpp evaluate --json`` writes) and a board (the API's
``Leaderboard``, as a dict). Every figure keeps its 95 % bootstrap interval over groups and every file its
provenance (robobpp/provenance.py): a table's note names the versions, machine, protocol, split, seed and
groups it was made with; the CSVs carry them in columns. A board's table also names its server and the date it
was exported, as docs/reporting.md asks of a relative score.

Markdown writes a figure on one line, "0.3194 [0.2393, 0.3911]". LaTeX is compact, about half as wide: three
decimals, the interval in small type under its figure ("0.319" over "0.239--0.391"), long headers and the
terminations on several lines; ``wide`` makes it a ``table*`` across both columns of a two-column paper, whose
single column even nine compact columns exceed (docs/reporting.md, "A table in a paper"). The
interval stays an interval rather than a ``±`` half-width because bootstrap intervals are not symmetric (a
utilisation near its ceiling has a short upper arm): a ``±`` would misstate one end.
"""

from __future__ import annotations

import csv
import io
import math
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, date, datetime
from typing import Any
from urllib.parse import urlsplit

from robobpp.episode import TERMINATION_REASONS, TERMINATION_SHORT
from robobpp.paper import place_in_order
from robobpp.provenance import FIELDS, merge, one_line
from robobpp.scoring.metrics import METRIC_BY_KEY, METRICS, metrics_for
from robobpp.vocabulary import CLOSED, DATASETS, PAPER, SETTINGS

FORMATS = ("csv", "md", "latex")


@dataclass(frozen=True, slots=True)
class Figure:
    """A figure with its interval: one cell, which each format lays out its own way."""

    value: float | None
    interval: tuple[float, float] | None
    digits: int = 4
    #: A figure with a unit (seconds, metres) spans orders of magnitude: LaTeX gives it significant figures,
    #: so that a decision time of 0.0011 s does not print as 0.001.
    significant: bool = False


@dataclass(frozen=True, slots=True)
class Lines:
    """A cell of several short parts (one per termination reason): one line in Markdown, stacked in LaTeX."""

    parts: tuple[str, ...]


Cell = str | Figure | Lines


@dataclass(slots=True)
class Sheet:
    """A table: a title, column headers, rows of cells and a note (provenance, interval method)."""

    title: str
    headers: list[str]
    rows: list[list[Cell]] = field(default_factory=list)
    note: str = ""
    #: What the figures' intervals are ("bootstrap 95 % interval over groups"): each format says where it
    #: put them (Markdown in brackets, LaTeX in small type under the figure) before the note.
    intervals: str = ""


def _interval(low: Any, high: Any) -> tuple[float, float] | None:
    """Both ends of an interval, or None when the source has none (a board without resamples)."""
    return None if low is None or high is None else (float(low), float(high))


def ending_parts(terminations: Mapping[str, int]) -> tuple[str, ...]:
    """How episodes ended, most frequent first (ties in the order reasons are listed): ("collapse 18",
    "no place 12"). Reasons robobpp does not list (a server's ``worker_lost``) keep their key."""
    order = list(TERMINATION_REASONS)
    ranked = sorted(terminations.items(), key=lambda kv: (-kv[1], *place_in_order(kv[0], order)))
    return tuple(f"{TERMINATION_SHORT.get(reason, reason)} {count}" for reason, count in ranked if count)


def endings(terminations: Mapping[str, int]) -> str:
    """:func:`ending_parts` on one line, as docs/baselines.md writes them: "collapse 18, no place 12"."""
    return ", ".join(ending_parts(terminations))


def table_order(dataset: str, setting: str) -> tuple[tuple[int, str], tuple[int, str]]:
    """Sort key of a (dataset, setting) row as the paper's tables order them: repetitive, diverse, longboard;
    within a dataset math, physics, execution (the order ``robobpp evaluate`` prints)."""
    return place_in_order(dataset, DATASETS), place_in_order(setting, SETTINGS)


def source_line(server: str | None, exported: date) -> str:
    """Where and when a board was taken, for its caption: a relative score moves with every new entry."""
    where = f"{_public_url(server)}, " if server else ""
    return f"Exported from {where}{exported.isoformat()} (UTC)."


def _public_url(server: str) -> str:
    """The server's URL as a paper may print it: no credentials, query or trailing slash."""
    parts = urlsplit(server)
    if not parts.scheme or not parts.hostname:
        return server.rstrip("/")
    port = f":{parts.port}" if parts.port else ""
    return f"{parts.scheme}://{parts.hostname}{port}{parts.path}".rstrip("/")


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


def _figure_cell(value: float | None, interval: Sequence[Any] | None, digits: int = 4) -> Figure:
    return Figure(value, _interval(*interval) if interval else None, digits)


def _metric_cell(key: str, value: float | None, interval: Sequence[Any] | None) -> Figure:
    """A metric's figure: significant figures in LaTeX when it has a unit, three decimals for a ratio."""
    return Figure(
        value, _interval(*interval) if interval else None, significant=bool(METRIC_BY_KEY[key].unit)
    )


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
        "machine",
        "anchors",
        "seed",
        "groups",
    ]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(head)
    for e in sorted(
        episodes,
        key=lambda e: (*table_order(e["dataset"], e["setting"]), e.get("protocol", ""), e["group"]),
    ):
        metrics = e.get("metrics") or {}
        writer.writerow(
            [
                _cell(v)
                for v in (
                    payload.get("policy"),
                    e["dataset"],
                    e["setting"],
                    e.get("protocol", CLOSED),
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
                    run.get("machine"),
                    run.get("anchors"),
                    payload.get("seed"),
                    payload.get("groups"),
                )
            ]
        )
    return out.getvalue()


def run_sheet(payload: Mapping[str, Any]) -> Sheet:
    """The summary of a local run: each (dataset, setting) in the paper's order with its figures and
    intervals, the boxes placed (mean per episode) and how the episodes ended (docs/reporting.md)."""
    runs = sorted(payload.get("runs") or [], key=lambda r: table_order(r["dataset"], r["setting"]))
    keys = [m.key for m in METRICS if any(m.key in (r.get("metrics") or {}) for r in runs)]
    sheet = Sheet(
        f"robobpp evaluate · {payload.get('policy')}",
        [
            "dataset",
            "setting",
            "episodes",
            "boxes placed",
            *(_label(k) for k in keys),
            "stable score ↑",
            "terminations",
        ],
    )
    for r in runs:
        intervals = r.get("intervals") or {}
        boxes = r.get("boxes_placed")
        sheet.rows.append(
            [
                r["dataset"],
                r["setting"],
                str(r["episodes"]),
                "—" if boxes is None else f"{boxes:.1f}",
                *(_metric_cell(k, (r.get("metrics") or {}).get(k), intervals.get(k)) for k in keys),
                _figure_cell(r.get("stable"), r.get("stable_interval"), 3),
                Lines(ending_parts(r.get("terminations") or {})),
            ]
        )
    confidence = float(payload.get("confidence") or 0.95)
    sheet.intervals = f"bootstrap {100 * confidence:.0f} % interval over groups"
    sheet.note = one_line(payload.get("provenance") or {})
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
        "protocol": board.get("protocol", CLOSED),
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
        board.get("protocol", CLOSED),
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


def board_sheet(
    board: Mapping[str, Any], *, server: str | None = None, exported: date | None = None
) -> Sheet:
    """A board as a summary table: rank (interval), entry, metrics, both scores with their intervals; its
    note says which server it came from and when (today, UTC, unless ``exported`` is given)."""
    keys = list(board.get("metrics") or [])
    protocol = " · paper protocol" if board.get("protocol") == PAPER else ""  # closed loop goes unsaid
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
                *(_metric_cell(k, (e.get("metrics") or {}).get(k), intervals.get(k)) for k in keys),
                _figure_cell(e.get("score"), (e.get("score_low"), e.get("score_high")), 3),
                _figure_cell(e.get("stable"), (e.get("stable_low"), e.get("stable_high")), 3),
            ]
        )
    confidence = float(board.get("confidence") or 0.95)
    sheet.intervals = f"bootstrap {100 * confidence:.0f} % interval over groups"
    sheet.note = (
        f"{source_line(server, exported or today())} Rank (interval): the ranks in "
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
            grid.get("protocol", CLOSED),
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


def grid_sheet(grid: Mapping[str, Any], *, server: str | None = None, exported: date | None = None) -> Sheet:
    """The overall grid as the paper's table: each board's score (rank), the Mean with its interval; its note
    says which server it came from and when."""
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
                _figure_cell(r.get("mean"), (r.get("mean_low"), r.get("mean_high")), 3),
                _figure_cell(r.get("stable"), (r.get("stable_low"), r.get("stable_high")), 3),
            ]
        )
    split = SPLIT_OF_TRACK.get(str(grid.get("track")), grid.get("track"))
    sheet.note = (
        f"{source_line(server, exported or today())} Each board: relative score (rank). Mean over {grid.get('boards')} boards with its bootstrap 95 % "
        f"interval; rank (interval) in 95 % of resamples; split {split}; lookahead {grid.get('lookahead', 0)}. "
        "Each board's provenance: robobpp leaderboard --dataset D --setting S"
        + (f" --lookahead {grid['lookahead']}" if grid.get("lookahead") else "")
        + " --format csv."
    )
    return sheet


# -- rendering --------------------------------------------------------------------------------------------
def today() -> date:
    """The export's date: UTC, so that two co-authors in different time zones print the same day."""
    return datetime.now(UTC).date()


def _markdown_cell(cell: Cell) -> str:
    if isinstance(cell, Figure):
        return _figure(cell.value, cell.interval, cell.digits)
    if isinstance(cell, Lines):
        return ", ".join(cell.parts) or "—"
    return cell


def markdown(sheet: Sheet) -> str:
    def esc(text: str) -> str:
        return text.replace("|", "\\|")

    lines = [
        f"**{esc(sheet.title)}**",
        "",
        "| " + " | ".join(map(esc, sheet.headers)) + " |",
        "|" + "|".join("---" if i < 2 else "---:" for i in range(len(sheet.headers))) + "|",
    ]
    lines += ["| " + " | ".join(esc(_markdown_cell(c)) for c in row) + " |" for row in sheet.rows]
    note = f"Brackets: {sheet.intervals}. {sheet.note}" if sheet.intervals else sheet.note
    if note:
        lines += ["", esc(note)]
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

#: Decimals of a figure and its interval in LaTeX: three tell 0.586 from 0.568, the resolution of 30 groups
#: (docs/reporting.md); a fourth only widens nine columns that must fit one.
LATEX_DECIMALS = 3
#: Significant figures of a LaTeX figure with a unit (Decision Time, Local Stability, Trajectory Length).
LATEX_SIGNIFICANT = 3
#: Characters per line of a LaTeX header: "Space Utilization ↑" becomes two lines no wider than its figures.
LATEX_HEADER_WIDTH = 10
#: What stays on the line of the word before it when a header wraps: an arrow, a unit.
_GLUED = (" ↑", " ↓", " (")


def latex_escape(text: str) -> str:
    return "".join(_LATEX.get(ch, ch) for ch in text)


def _latex_stack(lines: Sequence[str], *, align: str, anchor: str) -> str:
    """Lines stacked in one cell with plain LaTeX (a nested ``tabular``: no makecell, no package). ``anchor``
    ``t`` keeps the first line on the row's baseline (a figure beside plain cells), ``b`` the last (headers
    sit on the rule under them)."""
    if len(lines) == 1:
        return lines[0]
    return rf"\begin{{tabular}}[{anchor}]{{@{{}}{align}@{{}}}}" + r"\\".join(lines) + r"\end{tabular}"


def _latex_cell(cell: Cell) -> str:
    """A figure over its interval in small type ("0.319" over "0.239--0.391"); terminations one per line in
    small type; text escaped."""
    if isinstance(cell, Figure):
        if cell.value is None:
            return "---"
        digits = _significant_decimals(cell.value) if cell.significant else min(cell.digits, LATEX_DECIMALS)
        value = f"{cell.value:.{digits}f}"
        if cell.interval is None:
            return value
        low, high = cell.interval
        return _latex_stack(
            [value, rf"\scriptsize {low:.{digits}f}--{high:.{digits}f}"], align="r", anchor="t"
        )
    if isinstance(cell, Lines):
        if not cell.parts:
            return "---"
        return _latex_stack([rf"\scriptsize {latex_escape(p)}" for p in cell.parts], align="l", anchor="t")
    return latex_escape(cell)


def _significant_decimals(value: float) -> int:
    """Decimals that show ``value`` to :data:`LATEX_SIGNIFICANT` significant figures (0.00110, 0.0234, 12.3)."""
    if value == 0 or not math.isfinite(value):
        return LATEX_DECIMALS
    return max(0, LATEX_SIGNIFICANT - 1 - math.floor(math.log10(abs(value))))


def _latex_header(header: str, align: str) -> str:
    """A header on lines of about :data:`LATEX_HEADER_WIDTH` characters, an arrow or unit never alone on one
    (a no-break space glues it while wrapping: textwrap does not break there)."""
    glued = header
    for mark in _GLUED:
        glued = glued.replace(mark, "\u00a0" + mark[1:])
    lines = textwrap.wrap(glued, LATEX_HEADER_WIDTH, break_long_words=False) or [header]
    return _latex_stack(
        [latex_escape(line.replace("\u00a0", " ")) for line in lines], align=align, anchor="b"
    )


def _latex_note(sheet: Sheet) -> str:
    return (
        f"Small type under a figure: its {sheet.intervals}. {sheet.note}" if sheet.intervals else sheet.note
    )


def latex(sheet: Sheet, *, wide: bool = False) -> str:
    """A ``table`` with a ``tabular`` (booktabs rules: ``\\usepackage{booktabs}``) and the note as caption;
    ``wide``: a ``table*``, across both columns of a two-column paper."""
    aligns = ["l", "l"] + ["r"] * (len(sheet.headers) - 2)
    if sheet.rows and any(isinstance(row[-1], Lines) for row in sheet.rows):
        aligns[-1] = "l"  # terminations read as text
    env = "table*" if wide else "table"
    lines = [
        rf"\begin{{{env}}}",
        r"\centering",
        r"\small",
        r"\setlength{\tabcolsep}{4pt}",  # local to the float: the paper's other tables keep theirs
        rf"\begin{{tabular}}{{{''.join(aligns)}}}",
        r"\toprule",
        " & ".join(_latex_header(h, a) for h, a in zip(sheet.headers, aligns, strict=True)) + r" \\",
        r"\midrule",
    ]
    lines += [" & ".join(_latex_cell(c) for c in row) + r" \\" for row in sheet.rows]
    lines += [
        r"\bottomrule",
        r"\end{tabular}",
        rf"\caption{{{latex_escape(sheet.title)}. {latex_escape(_latex_note(sheet))}}}",
        rf"\end{{{env}}}",
    ]
    return "\n".join(lines) + "\n"


def render_run(payload: Mapping[str, Any], fmt: str, *, wide: bool = False) -> str:
    """A local run in ``fmt``: ``csv`` (per group), ``md`` or ``latex`` (summary; ``wide``: ``table*``)."""
    if fmt == "csv":
        return group_csv(payload)
    return _render(run_sheet(payload), fmt, wide=wide)


def render_board(
    board: Mapping[str, Any],
    fmt: str,
    *,
    server: str | None = None,
    exported: date | None = None,
    wide: bool = False,
) -> str:
    """A board in ``fmt``: ``csv`` (per entry), ``md`` or ``latex`` (summary, captioned with ``server`` and
    the export's date)."""
    if fmt == "csv":
        return board_csv(board)
    return _render(board_sheet(board, server=server, exported=exported), fmt, wide=wide)


def render_grid(
    grid: Mapping[str, Any],
    fmt: str,
    *,
    server: str | None = None,
    exported: date | None = None,
    wide: bool = False,
) -> str:
    """The overall grid in ``fmt``: ``csv`` (per submission), ``md`` or ``latex`` (the paper's table)."""
    if fmt == "csv":
        return grid_csv(grid)
    return _render(grid_sheet(grid, server=server, exported=exported), fmt, wide=wide)


def _render(sheet: Sheet, fmt: str, *, wide: bool = False) -> str:
    if fmt == "md":
        return markdown(sheet)
    if fmt == "latex":
        return latex(sheet, wide=wide)
    raise ValueError(f"unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
