"""Small helpers shared by the CLI modules: clear failures and choice parsing."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable
from typing import Annotated, NoReturn

import typer
from rich.console import Console

_err = Console(stderr=True)

#: ``--dataset`` of every command that takes datasets.
DatasetOpt = Annotated[str, typer.Option(help="repetitive, diverse, longboard, a comma list, or all.")]


def fail(message: str, code: int = 2) -> NoReturn:
    """Print a one-line error and exit non-zero (no traceback for user mistakes)."""
    _err.print(f"[bold red]error:[/] {message}", soft_wrap=True)  # one line: greppable, copyable
    raise typer.Exit(code)


def table_console() -> Console:
    """Stdout console for tables: a terminal's own width; files and pipes get whole tables, not 80 columns."""
    probe = Console()
    return probe if probe.is_terminal else Console(width=240)


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


def import_from_cwd(policy: str) -> None:
    """Let a ``module:Class`` policy name a module in the current directory, as ``python -m`` does.

    The ``robobpp`` console script puts only its own directory on ``sys.path``, so a participant's
    ``mypolicy.py`` in the working directory was "No module named 'mypolicy'".
    """
    if ":" in policy and not policy.startswith(("http://", "https://")):
        cwd = os.getcwd()
        if cwd not in sys.path and "" not in sys.path:
            sys.path.insert(0, cwd)


def settings_problem(exc: Exception) -> str:
    """One line per invalid setting, named by its environment variable.

    pydantic's own text adds the input it was given, the whole settings dict, which can hold the admin
    token or database password; this keeps only what is wrong.
    """
    from pydantic import ValidationError

    if not isinstance(exc, ValidationError):
        return str(exc)
    parts = []
    for error in exc.errors(include_input=False, include_url=False, include_context=False):
        message = str(error["msg"]).removeprefix("Value error, ")
        where = ".".join(str(part) for part in error["loc"])
        parts.append(f"ROBOBPP_{where.upper()}: {message}" if where else message)
    return "; ".join(parts)
