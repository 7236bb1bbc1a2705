"""Boxes, containers and placements, in centimetres (docs/benchmark.md, "Units and frames")."""

from __future__ import annotations

import math
from dataclasses import dataclass

#: The two orientations of the paper's robot settings: 0 = length along x, 1 = rotated 90° about z.
ORIENTATIONS: tuple[int, ...] = (0, 1)


def box_label(index: int) -> str:
    """A box of an episode in user-facing text: its index (0-based, as in traces and the API) and its place in
    the sequence, which is what "38 / 80 boxes placed" counts: ``box_label(37)`` is "box #37 (the 38th)"."""
    n = index + 1
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"box #{index} (the {n}{suffix})"


@dataclass(frozen=True, slots=True)
class Box:
    """One item to pack: dimensions in cm, mass in kg."""

    length: float
    width: float
    height: float
    mass: float = 1.0

    def __post_init__(self) -> None:
        length, width, height, mass = self.length, self.width, self.height, self.mass
        if (  # the usual case, checked without a loop: a sampled group builds 80 boxes at every env reset
            type(length) is float
            and type(width) is float
            and type(height) is float
            and type(mass) is float
            and 0 < length < math.inf
            and 0 < width < math.inf
            and 0 < height < math.inf
            and 0 < mass < math.inf
        ):
            return
        for name in ("length", "width", "height", "mass"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"box {name} must be a finite number > 0, got {value!r}")

    @property
    def volume(self) -> float:
        return self.length * self.width * self.height

    def dims(self, orientation: int) -> tuple[float, float, float]:
        """Extent along (x, y, z) of the box placed with ``orientation``."""
        return oriented_dims(self.length, self.width, self.height, orientation)


def oriented_dims(length: float, width: float, height: float, orientation: int) -> tuple[float, float, float]:
    if orientation == 0:
        return length, width, height
    if orientation == 1:
        return width, length, height
    raise ValueError(f"unknown orientation {orientation!r}; expected one of {ORIENTATIONS}")


@dataclass(frozen=True, slots=True)
class ContainerSpec:
    """Inner size of the container (or pallet footprint and height limit), cm."""

    length: float
    width: float
    height: float

    def __post_init__(self) -> None:
        for name in ("length", "width", "height"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"container {name} must be finite and > 0, got {value!r}")

    @property
    def volume(self) -> float:
        return self.length * self.width * self.height

    @property
    def grid_shape(self) -> tuple[int, int]:
        """Heightmap shape: one 1 cm cell per started centimetre of length and width."""
        return math.ceil(self.length - 1e-9), math.ceil(self.width - 1e-9)


@dataclass(frozen=True, slots=True)
class Placement:
    """A box in the container: min corner (x, y), bottom z, oriented extents, all in cm.

    ``quaternion`` (x, y, z, w) is the actual attitude in Physics/Execution Pack; ``None`` means upright.
    """

    x: float
    y: float
    z: float
    length: float  # extent along x
    width: float  # extent along y
    height: float  # extent along z
    orientation: int
    index: int  # position of the box in the episode's sequence
    quaternion: tuple[float, float, float, float] | None = None

    @property
    def volume(self) -> float:
        return self.length * self.width * self.height

    @property
    def top(self) -> float:
        return self.z + self.height

    @property
    def center(self) -> tuple[float, float, float]:
        return (self.x + self.length / 2, self.y + self.width / 2, self.z + self.height / 2)
