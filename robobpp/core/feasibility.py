"""Whether an action may be executed at all: finite numbers, known orientation, inside the container."""

from __future__ import annotations

import math
from dataclasses import dataclass

from robobpp.core.box import ORIENTATIONS, Box, ContainerSpec

#: Slack for floating-point noise at the container walls, cm.
TOLERANCE_CM = 1e-6


@dataclass(frozen=True, slots=True)
class Infeasible:
    """Why an action was refused; ``reason`` is a termination-reason code, ``detail`` plain words."""

    reason: str
    detail: str


def check_action(
    x: object, y: object, orientation: object, box: Box, container: ContainerSpec, z: float | None = None
) -> Infeasible | None:
    """Check an action against the container bounds; ``z`` (the resting height) adds the height check.

    Returns ``None`` when the action is feasible. Inputs may come from an untrusted policy, so types are
    checked here rather than assumed.
    """
    for name, value in (("x", x), ("y", y)):
        if isinstance(value, bool) or not isinstance(value, int | float):
            return Infeasible("invalid_action", f"{name} must be a number, got {type(value).__name__}")
        if not math.isfinite(value):
            return Infeasible("invalid_action", f"{name} is not finite ({value!r})")
    if isinstance(orientation, bool) or not isinstance(orientation, int) or orientation not in ORIENTATIONS:
        return Infeasible(
            "invalid_action", f"unknown orientation {orientation!r}; expected one of {ORIENTATIONS}"
        )
    length, width, height = box.dims(orientation)
    assert isinstance(x, int | float) and isinstance(y, int | float)
    if x < -TOLERANCE_CM or y < -TOLERANCE_CM:
        return Infeasible("out_of_bounds", f"footprint starts outside the container at ({x:g}, {y:g}) cm")
    if x + length > container.length + TOLERANCE_CM or y + width > container.width + TOLERANCE_CM:
        return Infeasible(
            "out_of_bounds",
            f"footprint [{x:g}, {x + length:g}] × [{y:g}, {y + width:g}] cm exceeds the container "
            f"{container.length:g} × {container.width:g} cm",
        )
    if z is not None and z + height > container.height + TOLERANCE_CM:
        return Infeasible(
            "too_high",
            f"box top at {z + height:g} cm would exceed the container height {container.height:g} cm",
        )
    return None
