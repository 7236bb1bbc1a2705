"""Helpers shared by the benchmark scripts: percentiles and a machine line for BENCHMARKS.md."""

from __future__ import annotations

import os
import platform
import statistics
import time


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    k = min(len(ordered) - 1, max(0, round(q / 100 * (len(ordered) - 1))))
    return ordered[k]


def median(values: list[float]) -> float:
    return statistics.median(values) if values else float("nan")


def machine() -> str:
    from robobpp.provenance import cpu_model  # the CPU's name as results record it (platform often has none)

    return f"{cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}"


class CpuPerStep:
    """An ``on_step`` callback for ``run_episode``: CPU seconds spent on each step (decision + apply + metrics).

    Measured between consecutive callbacks, so the first step includes the episode's set-up.
    """

    def __init__(self) -> None:
        self.per_box: list[float] = []
        self._last = time.process_time()

    def __call__(self, _record: object) -> None:
        now = time.process_time()
        self.per_box.append(now - self._last)
        self._last = now
