"""What a simulator reads off an episode for the metrics to use: where each box ended, how still a pile is.

They live in core so that the simulators (which produce them) and the benchmark's metrics
(``robobpp.scoring.metrics``, which consume them) need not import each other.
"""

from __future__ import annotations

from dataclasses import dataclass

from robobpp.core.box import Placement


@dataclass(slots=True)
class FinalBox:
    """A placed box at the end of the episode: where it was meant to be and where it is."""

    planned: Placement
    actual: Placement
    in_place: bool


def static_stability(max_linear_speed: float, max_angular_speed: float) -> float:
    """The Static Stability reading of one settle, from the largest speeds seen in its stability window:
    R = 0.5·clip(1 − v^0.4, 0, 1) + 0.5·clip(1 − ω^0.3, 0, 1) (v in m/s, ω in rad/s)."""
    v = max(0.0, max_linear_speed)
    w = max(0.0, max_angular_speed)
    stability: float = 0.5 * min(1.0, max(0.0, 1.0 - v**0.4)) + 0.5 * min(1.0, max(0.0, 1.0 - w**0.3))
    return stability
