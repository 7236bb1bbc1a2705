"""The fidelity criterion (docs/validation/physics.md, "Fidelity"): when two simulations of one episode agree, and the
paired test that says whether a mode agrees with the full simulation as often as the full simulation agrees
with itself. Pure Python, shared by ``bench/fidelity_physics.py`` and the CI test.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple, Protocol

#: Two runs of an episode may place this many boxes more or fewer and still agree.
BOXES_SLACK = 1
#: ... and their Local Stability may differ by this much, metres.
LOCAL_STABILITY_M = 0.005


class EpisodeEnd(Protocol):
    """What the criterion reads of an episode's result (``robobpp.episode.EpisodeResult`` has it): described
    here rather than imported, so the simulator never imports the episode loop above it."""

    @property
    def termination(self) -> str: ...
    @property
    def boxes_placed(self) -> int: ...
    @property
    def metrics(self) -> Mapping[str, float | None]: ...


class Outcome(NamedTuple):
    """What the criterion compares of one run: how it ended, boxes placed, Local Stability (m)."""

    termination: str
    boxes_placed: int
    local_stability_m: float

    @classmethod
    def of(cls, result: EpisodeEnd) -> Outcome:
        return cls(result.termination, result.boxes_placed, result.metrics.get("local_stability") or 0.0)


@dataclass(frozen=True, slots=True)
class Agreement:
    same_termination: bool
    same_boxes: bool
    same_local_stability: bool

    @property
    def agree(self) -> bool:
        return self.same_termination and self.same_boxes and self.same_local_stability


def compare(a: Outcome, b: Outcome) -> Agreement:
    """Same termination reason, boxes placed within ±``BOXES_SLACK``, Local Stability within 5 mm."""
    return Agreement(
        a.termination == b.termination,
        abs(a.boxes_placed - b.boxes_placed) <= BOXES_SLACK,
        abs(a.local_stability_m - b.local_stability_m) <= LOCAL_STABILITY_M + 1e-12,
    )


def mcnemar_one_sided(only_first: int, only_second: int) -> float:
    """Exact one-sided McNemar test on paired agreements: the probability of at least ``only_first``
    episodes where only the first comparison disagrees, out of the ``only_first + only_second`` discordant
    ones, if either comparison were as likely to be the one that disagrees (Binomial(n, 1/2) tail)."""
    if only_first < 0 or only_second < 0:
        raise ValueError("counts must be >= 0")
    n = only_first + only_second
    return sum(math.comb(n, i) for i in range(only_first, n + 1)) / 2**n if n else 1.0
