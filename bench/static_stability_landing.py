"""How a box lands decides Static Stability (docs/validation/physics.md, "Static Stability against the reference").

One box lands on the bare deck, or on a box that has settled there, under three landings: version 4's (a box
primitive released at rest 2 mm above its resting height), a primitive lowered 1 mm per step until it touches,
and version 5's (the reference's: a convex mesh loaded from a URDF, lowered 1 mm per step until it touches).
Printed per case, as a Markdown table: the largest linear speed v (m/s) and angular speed ω (rad/s) of any box
over the 200 steps after the landing, the Static Stability R they give, and where the box rests above its
support (mm; the mesh is made 1 mm smaller than the box on every side for Bullet's 1 mm margin, so it rests
on its real size).

    python bench/static_stability_landing.py
"""

from __future__ import annotations

from robobpp.core import ContainerSpec, static_stability
from robobpp.sim.physics.config import PhysicsConfig
from robobpp.sim.physics.world import PhysicsWorld

LANDINGS = {
    "version 4: primitive released 2 mm above": PhysicsConfig(collision_shape="box", release="gap"),
    "primitive lowered 1 mm per step": PhysicsConfig(collision_shape="box", release="lower"),
    "version 5: mesh lowered 1 mm per step": PhysicsConfig(),
}
BOXES = ((40.0, 30.0, 20.0), (25.0, 20.0, 15.0), (60.0, 40.0, 5.0))
SUPPORT = (50.0, 40.0, 30.0)
WINDOW = 200


def land(config: PhysicsConfig, extents: tuple[float, float, float], on_a_box: bool) -> tuple[float, ...]:
    """(v max, ω max, R, rest above the support in mm) of one landing in the middle of a 120 × 100 cm deck."""
    with PhysicsWorld(config) as world:
        world.add_pallet(ContainerSpec(120, 100, 100))
        support_top, moving = 0.0, []
        if on_a_box:
            below = world.add_box((60, 50, SUPPORT[2] / 2 + 0.05), SUPPORT, 0.5)
            world.step(600)  # settled
            support_top = world.pose_cm(below)[0][2] + SUPPORT[2] / 2
            moving.append(below)
        start = config.lower_from_cm if config.release == "lower" else config.release_gap_cm
        box = world.add_box((60, 50, support_top + extents[2] / 2 + start), extents, 0.5)
        moving.append(box)
        if config.release == "lower":
            world.lower_until_contact(box, start, config.lower_step_cm)
        v_max = w_max = 0.0
        for _ in range(WINDOW):
            world.step()
            v, w = world.speeds(moving)
            v_max, w_max = max(v_max, v), max(w_max, w)
        rest_mm = (world.pose_cm(box)[0][2] - extents[2] / 2 - support_top) * 10
    return v_max, w_max, static_stability(v_max, w_max), rest_mm


def main() -> None:
    print("| landing | box (cm) | on | v max (m/s) | ω max (rad/s) | R | rests above its support (mm) |")
    print("|---|---|---|---:|---:|---:|---:|")
    for name, config in LANDINGS.items():
        for extents in BOXES:
            for on_a_box in (False, True):
                v, w, r, rest = land(config, extents, on_a_box)
                size = "×".join(f"{e:g}" for e in extents)
                on = "a box" if on_a_box else "the deck"
                print(f"| {name} | {size} | {on} | {v:.3f} | {w:.3f} | {r:.3f} | {rest:+.2f} |")


if __name__ == "__main__":
    main()
