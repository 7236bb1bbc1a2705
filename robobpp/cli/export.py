"""``robobpp export``: a local run (``robobpp evaluate --json``) as a per-group CSV or a summary table in
Markdown or LaTeX; boards export through ``robobpp leaderboard --format`` (robobpp/export.py)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from robobpp.cli.common import fail

FormatOpt = Annotated[
    str, typer.Option("--format", help="csv (one row per group), md or latex (summary table).")
]
WideOpt = Annotated[
    bool,
    typer.Option(
        "--wide",
        help="LaTeX: a table* across both columns of a two-column paper (default: a one-column table).",
    ),
]


def register(root: typer.Typer) -> None:
    root.command("export")(export)


def export(
    result: Annotated[Path, typer.Argument(help="A file written by `robobpp evaluate --json`.")],
    fmt: FormatOpt = "md",
    out: Annotated[Path | None, typer.Option(help="Write here instead of stdout.")] = None,
    wide: WideOpt = False,
) -> None:
    """Export a local run: per-group CSV, or its summary (figures with 95 % intervals, provenance) in
    Markdown or LaTeX."""
    from robobpp.export import FORMATS, render_run

    if fmt not in FORMATS:
        fail(f"unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
    try:
        payload = json.loads(result.read_text(encoding="utf-8"))
        text = render_run(payload, fmt, wide=wide)
    except OSError as exc:
        fail(f"{result}: cannot read ({exc.strerror})")
    except (ValueError, KeyError, TypeError) as exc:
        fail(f"{result}: not a `robobpp evaluate --json` file ({type(exc).__name__}: {exc})")
    write(text, out)


def write(text: str, out: Path | None) -> None:
    """``text`` to ``out`` (created whole, then renamed) or to stdout."""
    if out is None:
        typer.echo(text, nl=False)
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(out)
