"""Placeholder: the `robobpp worker` command (Celery executor) is registered here."""

from __future__ import annotations

import typer


def register(root: typer.Typer) -> None:
    return None
