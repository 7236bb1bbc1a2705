"""Math Pack: pure geometry. A box drops onto the heightmap under its footprint and never moves.

As in the reference's Math Pack (packsim runs its environment with the stability check off in setting 1), no
support rule applies: the box rests on the highest cell under it, overhang and all. No setting enforces the
support rule (:class:`robobpp.core.feasibility.SupportModel`), as in the reference, whose environment checks bounds
and height only; PCT applies it to its leaves in the physical settings. docs/baselines.md shows the experiment (the
paper's Math Pack figures are reproduced without it and missed with it).
"""

from __future__ import annotations

from robobpp.core import Action, Box, ContainerState, EpisodeSpec, FinalBox, Infeasible
from robobpp.sim.base import Setting, StepOutcome

#: Version of the Math Pack rules: which actions are accepted (``robobpp.core.check_action``: bounds,
#: orientations, finite numbers), where a box comes to rest (the drop onto the heightmap) and when it is too
#: high. Every setting applies them, every result records the version (``EpisodeResult.rules_version``) and
#: a board never mixes versions: a change that can alter any figure is a new version, as for physics.
#: 2: Occupancy is the reference's: the mean over placements of the placed volume over the volume under the
#: heightmap at that placement (version 1: once, on the final heightmap), docs/benchmark.md, "Metrics".
MATH_RULES_VERSION = "2"


class MathPack(Setting):
    name = "math"

    def __init__(self) -> None:
        self._state: ContainerState | None = None
        self._under: list[float] = []

    def reset(self, spec: EpisodeSpec) -> None:
        self._state = ContainerState(spec.container)
        self._under = []

    def state(self) -> ContainerState:
        assert self._state is not None, "reset() first"
        return self._state

    def apply(self, box: Box, action: Action, index: int) -> StepOutcome:
        state = self.state()
        placement, cells = state.drop_on_cells(box, action.x, action.y, action.orientation, index)
        if placement.top > state.spec.height + 1e-6:
            return StepOutcome(
                None,
                Infeasible(
                    "too_high",
                    f"box top at {placement.top:g} cm would exceed the container height {state.spec.height:g} cm",
                ),
            )
        state.add(placement, cells)
        # Occupancy's heightmaps are this state's: the plan is what was placed, in order (the same array, so the
        # same sum, as a replay would give)
        self._under.append(state.volume_under_heightmap())
        return StepOutcome(placement)

    def under_volumes(self) -> list[float]:
        return list(self._under)

    def final_boxes(self) -> list[FinalBox]:
        return [FinalBox(p, p, True) for p in self.state().placements]
