"""Small helpers shared by the CLI modules: clear failures and choice parsing."""

from __future__ import annotations

from collections.abc import Iterable
from typing import NoReturn

import typer
from rich.console import Console

_err = Console(stderr=True)


def fail(message: str, code: int = 2) -> NoReturn:
    """Print a one-line error and exit non-zero (no traceback for user mistakes)."""
    _err.print(f"[bold red]error:[/] {message}")
    raise typer.Exit(code)


def parse_choices(value: str, allowed: Iterable[str], what: str) -> list[str]:
    """``a,b`` or ``all`` → a list of known names; unknown names fail with the allowed list."""
    allowed = list(allowed)
    if value.strip().lower() == "all":
        return allowed
    names = [v.strip().lower() for v in value.split(",") if v.strip()]
    unknown = [n for n in names if n not in allowed]
    if not names or unknown:
        fail(
            f"unknown {what} {', '.join(unknown) or repr(value)}; expected one of {', '.join(allowed)} or all"
        )
    return names
