"""Physics Pack parameters (BENCHMARK.md §3). The defaults are the leaderboard's and stay fixed there.

Every figure that changes a physical outcome lives here, so a run can record exactly what it simulated
(``PhysicsConfig.to_dict``) and a participant's offline run matches the server's.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

from robobpp.core.feasibility import TOLERANCE_CM

#: ``full``: every placed box is dynamic and each placement runs at least the 200-step stability window
#: (the reference the fidelity test compares against). ``fast``: boxes far from the new one are frozen
#: (made static) and woken only when something moving comes near them, and the window stops early once
#: everything is at rest. Both are deterministic.
Mode = Literal["full", "fast"]


@dataclass(frozen=True, slots=True)
class PhysicsConfig:
    #: Simulation time step, seconds.
    dt: float = 1.0 / 240.0
    #: Gravity, m/s² (pointing down).
    gravity: float = 9.81
    #: Coulomb friction, box–box and box–floor.
    lateral_friction: float = 0.5
    restitution: float = 0.0
    #: Velocity damping per second (pybullet's defaults, kept explicit so they are recorded).
    linear_damping: float = 0.04
    angular_damping: float = 0.04
    #: Constraint solver iterations per step (pybullet's default).
    solver_iterations: int = 50
    #: Side walls around the pallet (the reference implementation has none: a pallet, not a bin).
    walls: bool = False
    #: Gap between the box's bottom and its computed resting height at release, cm.
    release_gap_cm: float = 0.2
    #: Horizontal slack when deciding what lies under a footprint, cm: a neighbour overlapping the
    #: footprint by less than this (settling noise, rounding to the 1 cm grid) does not lift the new box.
    edge_tolerance_cm: float = 0.5
    #: The observed heightmap is rounded to this, cm. Sub-millimetre settling noise then cannot flip a
    #: heightmap policy's choice (DBL weighs 0.01 cm of height like 1 cm of x), which keeps decisions
    #: reproducible across machines and between the fast and full simulation. 0 keeps the raw heights.
    heightmap_resolution_cm: float = 0.1
    #: Steps after each release over which Static Stability takes its max speeds (the paper's 200).
    stability_steps: int = 200
    #: Everything counts as at rest when every dynamic box moves slower than these (m/s, rad/s)...
    rest_linear: float = 0.005
    rest_angular: float = 0.05
    #: ... for this many consecutive steps.
    rest_steps: int = 10
    #: Cap on the steps simulated after one release (10 s of simulated time).
    max_steps: int = 2400
    mode: Mode = "fast"
    #: Fast mode: boxes whose footprint comes within this horizontal distance (cm) of a moving box are
    #: simulated; the others are frozen until something moving comes that near.
    wake_margin_cm: float = 10.0
    #: Fast mode: a box faster than this (m/s or rad/s) wakes its frozen neighbours.
    wake_speed: float = 0.01

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"physics {f.name} must be finite, got {value!r}")
        if self.dt <= 0 or self.dt > 0.1:
            raise ValueError(f"physics dt must be in (0, 0.1] s, got {self.dt!r}")
        if self.gravity <= 0:
            raise ValueError(f"physics gravity must be > 0, got {self.gravity!r}")
        if self.lateral_friction < 0 or self.restitution < 0 or self.restitution > 1:
            raise ValueError("friction must be >= 0 and restitution in [0, 1]")
        if (
            self.heightmap_resolution_cm < 0
            or self.release_gap_cm < 0
            or self.edge_tolerance_cm < 0
            or self.wake_margin_cm < 0
        ):
            raise ValueError("release gap, edge tolerance and wake margin must be >= 0")
        if min(self.solver_iterations, self.stability_steps, self.rest_steps, self.max_steps) < 1:
            raise ValueError("solver iterations and step counts must be >= 1")
        if self.mode not in ("full", "fast"):
            raise ValueError(f"physics mode must be 'full' or 'fast', got {self.mode!r}")

    @property
    def too_high_slack_cm(self) -> float:
        """How far (cm) a box's top may stand above the container height before the placement is refused
        as too_high: half the observed heightmap's rounding, which a policy cannot see through (a top
        computed from the rounded heightmap may be up to that much low). Both packs use it."""
        return max(TOLERANCE_CM, self.heightmap_resolution_cm / 2)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
