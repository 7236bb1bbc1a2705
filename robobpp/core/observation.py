"""What a policy sees and what it answers (the in-process form of protocol robobpp/1)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from robobpp.core.box import ORIENTATIONS, Box, ContainerSpec, Placement


@dataclass(frozen=True, slots=True)
class Action:
    """Place the current box with its footprint's min corner at (x, y) cm, in ``orientation``.

    z is not chosen: the box is released from above and comes to rest where the state lets it.
    """

    x: float
    y: float
    orientation: int
    #: Time the policy says it spent computing, seconds (kept beside the measured decision time).
    compute_time: float | None = None


@dataclass(frozen=True, slots=True)
class EpisodeInfo:
    """Sent to ``Policy.reset`` before the first box."""

    episode_id: str
    dataset: str
    setting: str
    container: ContainerSpec
    orientations: tuple[int, ...] = ORIENTATIONS
    lookahead: int = 0


@dataclass(frozen=True, slots=True)
class Observation:
    """The state a policy acts on.

    ``placed`` is the *actual* state (after physics in Physics/Execution Pack); ``heightmap`` is the
    container's 1 cm heightmap built from it (cm, shape ``container.grid_shape``): read-only, and the
    observation's own, so it stays as it was when observed while the episode goes on.
    """

    episode_id: str
    step: int
    container: ContainerSpec
    placed: tuple[Placement, ...]
    heightmap: np.ndarray
    box: Box
    lookahead: tuple[Box, ...] = ()
    orientations: tuple[int, ...] = ORIENTATIONS
    extra: dict[str, object] = field(default_factory=dict)
