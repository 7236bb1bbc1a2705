"""Placeholder: `robobpp submit` / `robobpp submissions` (API client of the evaluation server) go here."""

from __future__ import annotations

import typer


def register(root: typer.Typer) -> None:
    return None
