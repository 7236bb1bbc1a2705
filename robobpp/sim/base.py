"""The interface every test setting (Math, Physics, Execution Pack) offers to the episode loop."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

from robobpp.core import Action, Box, ContainerState, EpisodeSpec, FinalBox, Infeasible, Placement


@dataclass(slots=True)
class StepOutcome:
    """What applying one action did.

    ``placement`` is the new box's *actual* pose after the step (None when it was never released);
    ``termination`` ends the episode (too high, collapse, failed grasp...). The optional figures feed the
    metrics of the settings that measure them.
    """

    placement: Placement | None
    termination: Infeasible | None = None
    #: Static stability R of this placement (Physics/Execution), docs/benchmark.md, "Metrics".
    static_stability: float | None = None
    #: Whether this placement caused a collapse (any box displaced beyond the threshold or fallen off).
    collapsed: bool = False
    #: Tool-centre-point path length, metres (Execution).
    trajectory_length_m: float | None = None
    #: Unsafe grasp-and-place operation (Execution).
    dangerous: bool | None = None
    extra: dict[str, object] = field(default_factory=dict)


class Setting(ABC):
    """A test setting. One instance runs one episode at a time; ``reset`` starts the next."""

    name: str = ""

    @abstractmethod
    def reset(self, spec: EpisodeSpec) -> None: ...

    @abstractmethod
    def state(self) -> ContainerState:
        """The actual container state the policy observes (positions after physics, in cm)."""

    @abstractmethod
    def apply(self, box: Box, action: Action, index: int) -> StepOutcome:
        """Execute a bounds-checked action for box number ``index``."""

    @abstractmethod
    def final_boxes(self) -> list[FinalBox]:
        """Planned vs actual pose of every placed box, read at the end of the episode."""

    def plan(self) -> list[Placement]:
        """Where each placed box was meant to go, in placement order: the pile its policy planned on, which
        Occupancy reads (the reference computes it on its idealised heightmap). By default the planned pose
        of each of ``final_boxes()``."""
        return [f.planned for f in self.final_boxes()]

    def under_volumes(self) -> list[float] | None:
        """The volume under the heightmap of :meth:`plan` after each of its placements, when the setting keeps
        them as it goes (Occupancy then needs no replay); None by default."""
        return None

    @property
    def physics_version(self) -> str | None:
        """The version of the physics behind this setting's outcomes (recorded with every result; boards
        never mix versions); None for a setting without physics (Math Pack)."""
        return None

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release simulator resources."""
