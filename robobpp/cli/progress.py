"""The CLI's progress bar, also readable where no terminal draws it (a log file, a batch job)."""

from __future__ import annotations

import time
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn, TimeElapsedColumn

#: Seconds between progress lines when the console is not a terminal.
PROGRESS_LINE_S = 30.0


class LineProgress(Progress):
    """rich's progress bar draws nothing off a terminal until it stops, so a ``submit --wait`` or a long
    ``evaluate`` in a batch job or ``> log`` printed nothing for the whole run. Off a terminal, this one also
    prints a plain line per task (description, done/total, elapsed) at most every ``every_s`` seconds."""

    def __init__(self, console: Console, every_s: float | None = None) -> None:
        columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
        super().__init__(*columns, console=console, transient=False)
        self._every_s = PROGRESS_LINE_S if every_s is None else every_s
        self._lines = not console.is_terminal
        self._last = time.monotonic()

    def update(self, task_id: TaskID, **kwargs: Any) -> None:
        super().update(task_id, **kwargs)
        self._line()

    def advance(self, task_id: TaskID, advance: float = 1) -> None:
        super().advance(task_id, advance)
        self._line()

    def _line(self) -> None:
        now = time.monotonic()
        if not self._lines or now - self._last < self._every_s:
            return
        self._last = now
        for task in self.tasks:
            total = f"/{task.total:g}" if task.total is not None else ""
            self.console.print(
                f"{task.description}: {task.completed:g}{total} · {task.elapsed or 0:.0f} s",
                markup=False,
                highlight=False,
                soft_wrap=True,
            )
