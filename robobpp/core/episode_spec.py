"""What one episode is: a dataset's container and an 80-box sequence (the unit of evaluation)."""

from __future__ import annotations

from dataclasses import dataclass

from robobpp.core.box import Box, ContainerSpec


@dataclass(frozen=True, slots=True)
class EpisodeSpec:
    dataset: str
    split: str
    group: int
    boxes: tuple[Box, ...]
    container: ContainerSpec
    #: Horizontal displacement (cm) beyond which a placed box counts as collapsed (dataset property).
    collapse_threshold_cm: float
    #: Seed the group was sampled with; also seeds anything random inside the episode (planner, Random).
    seed: int = 0
    #: ``robobpp.datasets.sampling.SAMPLER_VERSION`` of the sampler that drew the group (None: hand-built or
    #: synthetic boxes, or a set written before the version existed). Recorded with every result.
    sampler_version: str | None = None
    #: What the policy is told the episode is called, when not the readable default: the service gives each
    #: evaluated episode an opaque one, since ``repetitive-test-001`` names the split and the group.
    label: str | None = None

    @property
    def episode_id(self) -> str:
        return self.label or f"{self.dataset}-{self.split}-{self.group:03d}"
