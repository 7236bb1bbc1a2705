"""The paper's published figures (package data ``robobpp/data/paper_tables.json``), each with the table it is from.

Every metric the paper tabulates for its twelve methods, per setting and dataset: the appendix tables (one per
dataset and pack: Space Utilization, Occupancy, Decision Time, Local and Static Stability, and in Execution Pack
Trajectory Length, Collapsed Placement, Dangerous Operation), the overall score (``score``) and the
theoretical picks per hour (``pph``). The paper ran 30 groups of its private test pool per dataset; its Physics
and Execution figures are Math Pack plans replayed open loop (the ``paper`` protocol, :mod:`robobpp.replay`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from importlib import resources


def place_in_order(item: str, order: Sequence[str]) -> tuple[int, str]:
    """Sort key: ``order``'s items first, in its order, then the rest by name."""
    return (order.index(item) if item in order else len(order), item)


#: The paper's seven heuristics, in its order, then its learned policy that robobpp ships (PCT).
PAPER_HEURISTICS: tuple[str, ...] = ("dbl", "hm", "lsah", "onlinebph", "br", "macs", "sdfpack")
PAPER_BASELINES: tuple[str, ...] = (*PAPER_HEURISTICS, "pct")
#: Groups (episodes) behind each of the paper's figures: 30 of its private test pool per dataset.
PAPER_GROUPS = 30
#: Metrics the paper tabulates beyond robobpp's eight (docs/benchmark.md, "Metrics").
EXTRA_METRICS: dict[str, str] = {
    "pph": "theoretical picks per hour, 3600 / (Decision Time + Trajectory Length / 0.34 m/s + 2 s)",
    "score": "the paper's overall score: weighted min–max over its 12 methods",
}


@dataclass(frozen=True, slots=True)
class PaperValue:
    setting: str
    dataset: str
    #: robobpp's policy name where robobpp has the method (``dbl``), else the paper's in lower case.
    method: str
    metric: str
    value: float
    #: The LaTeX label of the paper's table (its caption: :attr:`PaperTables.tables`).
    table: str


@dataclass(frozen=True)
class PaperTables:
    paper: str
    about: str
    #: method key → the paper's spelling
    methods: dict[str, str]
    #: table label → caption
    tables: dict[str, str]
    values: tuple[PaperValue, ...]
    index: dict[tuple[str, str, str, str], PaperValue] = field(repr=False, compare=False)

    def get(self, setting: str, dataset: str, method: str, metric: str) -> PaperValue | None:
        """The paper's figure of ``method`` for ``metric`` in ``setting`` on ``dataset`` (None: not tabulated)."""
        return self.index.get((setting, dataset, method, metric))

    def metrics(self, setting: str) -> tuple[str, ...]:
        """The metrics the paper tabulates in ``setting``, in its order."""
        seen: dict[str, None] = {}
        for v in self.values:
            if v.setting == setting:
                seen.setdefault(v.metric)
        return tuple(seen)


@cache
def paper_tables() -> PaperTables:
    """The paper's figures, read once from the package data."""
    text = resources.files("robobpp").joinpath("data/paper_tables.json").read_text(encoding="utf-8")
    raw = json.loads(text)
    columns = raw["columns"]
    values = tuple(PaperValue(**dict(zip(columns, row, strict=True))) for row in raw["values"])
    index = {(v.setting, v.dataset, v.method, v.metric): v for v in values}
    return PaperTables(raw["paper"], raw["about"], dict(raw["methods"]), dict(raw["tables"]), values, index)


__all__ = [
    "EXTRA_METRICS",
    "PAPER_BASELINES",
    "PAPER_HEURISTICS",
    "PaperTables",
    "PaperValue",
    "paper_tables",
]
