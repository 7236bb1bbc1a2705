"""Physics Pack parameters (docs/benchmark.md, "Settings"). The defaults are the leaderboard's and stay fixed there.

Every figure that changes a physical outcome lives here, so a run can record exactly what it simulated
(``PhysicsConfig.to_dict``) and a participant's offline run matches the server's.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

from robobpp.core.feasibility import TOLERANCE_CM

#: ``full``: every placed box is dynamic and each placement runs at least the 200-step stability window
#: (the reference the fidelity test compares against). ``fast``: boxes far from the new one are frozen
#: (made static) and woken only when something moving comes near them, and the window stops early once
#: everything is at rest. Both are deterministic.
Mode = Literal["full", "fast"]
#: ``mesh``: each box collides as a convex mesh of a unit cube's eight corners scaled to the box, the reference
#: implementation's shape (Bullet gives it a 1 mm collision margin, so a box rests about 1 mm above what
#: carries it and touches early). ``box``: Bullet's box primitive (versions 1-4).
Shape = Literal["mesh", "box"]
#: ``lower``: the reference's landing: the box is put ``lower_from_cm`` above its resting height and lowered
#: ``lower_step_cm`` per simulation step until it touches anything, then let go with the speed of that step.
#: ``gap``: released at rest ``release_gap_cm`` above its resting height (versions 1-4).
Release = Literal["lower", "gap"]

#: The version of the simulated physics. Every stored result records it (``EpisodeResult.physics_version``,
#: the episodes table, ``evaluate --json``) and a board shows only results of the current one. Bump it
#: whenever a change to this package can change an outcome (a termination, a pose, a metric).
#: 1: friction 0.5, dataset masses, release into the footprint as chosen, collapse on the horizontal
#: distance. 2: the reference implementation's friction (1.0), mass (0.5 kg), collapse rule (|dx| or |dy|
#: over the threshold) and a release clear of the neighbours (docs/physics.md, "Against the reference").
#: 3: friction anchors on every contact (positional static friction), which removes the solver's creep of
#: piles at rest, and an observation that 0.1 mm of settling cannot flip: the heightmap claims a cell a box
#: covers by more than 2.5 mm (was 5 mm, exactly half a cell) and the observed placements are rounded to
#: 1 mm like the heightmap (docs/validation/physics.md, "Creep" and "Fidelity").
#: 4: the simulation is version 3's; the baselines' figures in it change: the paper's heuristics no longer apply
#: the support rule to their candidates (the reference's do not), so a board's version-3 baseline runs go
#: (docs/baselines.md, "Feasibility"). The Execution Pack ends where the reference ends: a place move that cannot
#: start (no IK solution, or the arm with its box in collision at the pre-place pose, now the reference's: the
#: box's top 0.35 m above its target's centre) and the third dangerous operation, its box not counted
#: (docs/validation/execution.md, "Against the reference implementation").
#: 5: Static Stability measured on the reference's landing: each box a convex mesh (``collision_shape``), put
#: 1.7 cm above its resting height and lowered 1 mm per step until it touches (``release``), as the reference
#: does; the window of 200 steps starts at that touch. Version 4's primitive box released at rest 2 mm above
#: its resting height read ≈ 0.6 where the paper's tables read ≈ 0.4 (docs/validation/physics.md, "Static Stability
#: against the reference").
PHYSICS_VERSION = "5"


@dataclass(frozen=True, slots=True)
class PhysicsConfig:
    #: Simulation time step, seconds.
    dt: float = 1.0 / 240.0
    #: Gravity, m/s² (pointing down).
    gravity: float = 9.81
    #: Coulomb friction of a contact pair, box–box and box–floor (the reference implementation's 1.0).
    lateral_friction: float = 1.0
    restitution: float = 0.0
    #: Velocity damping per second (pybullet's defaults, kept explicit so they are recorded).
    linear_damping: float = 0.04
    angular_damping: float = 0.04
    #: Constraint solver iterations per step (pybullet's default).
    solver_iterations: int = 50
    #: Friction anchors on every body (pybullet's ``frictionAnchor``): a sticking contact keeps its point
    #: and the solver corrects positional slip, so a pile at rest stays where it is. Off, a resting pile
    #: creeps by micrometres per step, a time-discretisation artefact that shrinks with the time step
    #: (``bench/physics_creep.py``, docs/validation/physics.md "Creep"). Sliding past μ is unchanged.
    friction_anchor: bool = True
    #: Every box is simulated with this mass, kg (the reference implementation's 0.5 kg for every box);
    #: None: the dataset's mass. Only the physics uses it: the Execution Pack's suction check keeps the
    #: dataset's mass.
    box_mass_kg: float | None = 0.5
    #: Release the box clear of a neighbour that reaches less than ``edge_tolerance_cm`` into its footprint
    #: (shifted horizontally by that overlap plus ``clear_gap_cm``), as the reference never releases a box
    #: into another; False releases it into the neighbour and the solver pushes the two apart.
    release_clear: bool = True
    clear_gap_cm: float = 0.01
    #: Side walls around the pallet (the reference implementation has none: a pallet, not a bin).
    walls: bool = False
    #: How a box collides (``Shape`` above; the reference's mesh by default).
    collision_shape: Shape = "mesh"
    #: How a box lands (``Release`` above; the reference's lowering by default).
    release: Release = "lower"
    #: ``lower``: how far above its resting height the box starts (the reference's ≈ 1.7 cm) and how far it
    #: is lowered per simulation step (the reference's 1 mm), cm.
    lower_from_cm: float = 1.7
    lower_step_cm: float = 0.1
    #: ``gap``: the gap between the box's bottom and its computed resting height at release, cm. The
    #: Execution Pack's robot also lets go of the box this far above its resting height.
    release_gap_cm: float = 0.2
    #: Horizontal slack when deciding what lies under a footprint, cm: a neighbour overlapping the
    #: footprint by less than this (settling noise, rounding to the 1 cm grid) does not lift the new box.
    edge_tolerance_cm: float = 0.5
    #: The observed heightmap claims a 1 cm cell for a box when the box's actual bounds, shrunk horizontally
    #: by this (cm), still reach into it, i.e. when the box covers more than this much of the cell. Box sides
    #: in the datasets are mostly multiples of 0.5 cm and actions lie on the 1 cm grid, so box edges sit at
    #: whole or half centimetres; a shrink of 0.25 cm keeps every such edge 2.5 mm from a cell boundary, so
    #: settling noise of a tenth of a millimetre cannot flip a whole row of cells, and a half-covered cell
    #: counts as covered, as in the Math Pack's heightmap. (Version 2 shrank by ``edge_tolerance_cm``,
    #: 0.5 cm, which put half-centimetre edges exactly on a cell boundary.)
    heightmap_shrink_cm: float = 0.25
    #: The observed heightmap is rounded to this, cm. Sub-millimetre settling noise then cannot flip a
    #: heightmap policy's choice (DBL weighs 0.01 cm of height like 1 cm of x), which keeps decisions
    #: reproducible across machines and between the fast and full simulation. 0 keeps the raw heights.
    heightmap_resolution_cm: float = 0.1
    #: The observed placements (``state().placements``, the min corner of each box's actual pose) are
    #: rounded to this, cm, for the same reason: a policy's own rules on them (the support rule's cells,
    #: ``floor``/``ceil`` of a corner the policy put on the 1 cm grid) must not flip on 0.1 mm of settling.
    #: Outcomes, metrics and the replay keep the unrounded poses. 0 keeps them raw.
    pose_resolution_cm: float = 0.1
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
        lengths = (
            "heightmap_resolution_cm",
            "release_gap_cm",
            "edge_tolerance_cm",
            "wake_margin_cm",
            "clear_gap_cm",
            "heightmap_shrink_cm",
            "pose_resolution_cm",
            "lower_from_cm",
        )
        if negative := [name for name in lengths if getattr(self, name) < 0]:
            raise ValueError(f"physics lengths must be >= 0: {', '.join(negative)}")
        if min(self.solver_iterations, self.stability_steps, self.rest_steps, self.max_steps) < 1:
            raise ValueError("solver iterations and step counts must be >= 1")
        if self.box_mass_kg is not None and not (math.isfinite(self.box_mass_kg) and self.box_mass_kg > 0):
            raise ValueError(f"physics box_mass_kg must be > 0 or None, got {self.box_mass_kg!r}")
        if not 0 < self.lower_step_cm <= 10:
            raise ValueError(f"physics lower_step_cm must be in (0, 10] cm, got {self.lower_step_cm!r}")
        if self.collision_shape not in ("mesh", "box"):
            raise ValueError(f"physics collision_shape must be 'mesh' or 'box', got {self.collision_shape!r}")
        if self.release not in ("lower", "gap"):
            raise ValueError(f"physics release must be 'lower' or 'gap', got {self.release!r}")
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

    @property
    def version(self) -> str:
        """``PHYSICS_VERSION`` for the validated defaults (either mode: fast is validated against full);
        otherwise that plus a short digest of the settings, so a result of changed physics never shares
        a board with the defaults'."""
        return versioned(self.changed())

    def changed(self) -> dict[str, Any]:
        """The settings that differ from the validated defaults (the mode aside: fast is validated against
        full)."""
        return {k: v for k, v in self.to_dict().items() if k != "mode" and v != getattr(_DEFAULTS, k)}


def versioned(changed: dict[str, Any]) -> str:
    """``PHYSICS_VERSION`` when nothing differs from the validated defaults, else that plus a short digest of
    what differs: a result of changed physics (or a changed robot) never shares a board with the defaults'."""
    if not changed:
        return PHYSICS_VERSION
    digest = hashlib.sha256(json.dumps(changed, sort_keys=True, default=str).encode()).hexdigest()[:8]
    return f"{PHYSICS_VERSION}+{digest}"


_DEFAULTS = PhysicsConfig()
