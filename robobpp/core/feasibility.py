"""Whether an action may be executed — finite numbers, known orientation, inside the container, below its top
(:func:`check_action`, what every setting enforces, as the reference's environment) — and the reference's support
rule (:class:`SupportModel`), which no setting enforces: information a policy may use."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from robobpp.core.box import ORIENTATIONS, Box, ContainerSpec, Placement

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
    # the usual case (an env's or a parsed answer's finite floats), checked without the loop below
    if (
        type(x) is float
        and type(y) is float
        and type(orientation) is int
        and orientation in ORIENTATIONS
        and math.isfinite(x)
        and math.isfinite(y)
    ):
        return _check_extent(x, y, *box.dims(orientation), container, z)
    for name, value in (("x", x), ("y", y)):
        if isinstance(value, bool) or not isinstance(value, int | float):
            return Infeasible("invalid_action", f"{name} must be a number, got {type(value).__name__}")
        if not math.isfinite(value):
            return Infeasible("invalid_action", f"{name} is not finite ({value!r})")
    if isinstance(orientation, bool) or not isinstance(orientation, int) or orientation not in ORIENTATIONS:
        return Infeasible(
            "invalid_action", f"unknown orientation {orientation!r}; expected one of {ORIENTATIONS}"
        )
    assert isinstance(x, int | float) and isinstance(y, int | float)
    return _check_extent(x, y, *box.dims(orientation), container, z)


def _check_extent(
    x: float, y: float, length: float, width: float, height: float, container: ContainerSpec, z: float | None
) -> Infeasible | None:
    """The bounds (and, with ``z``, height) part of :func:`check_action`, on checked numbers."""
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


# --- Support: the reference's geometric stability rule ---------------------------------------------------------
#
# The authors' PCT environment (shipped again inside packsim) generates its leaf nodes in the physical settings
# only where a recursive centre-of-mass test passes (its step itself checks bounds and height only); no physics is
# involved. In words:
#
# 1. The supports of a box are the placed boxes whose top is at the box's resting height and whose footprint
#    overlaps its footprint with positive area; each overlap is a contact rectangle.
# 2. The support polygon is the convex hull of the contact rectangles' corners, shrunk by 10 % towards the mean
#    of the hull's vertices. A box on the floor, or touching no support, needs no test.
# 3. Every box carries a load: its own mass at its centre plus what the boxes above pass down to it. The (x, y)
#    centre of that load must lie strictly inside the box's support polygon.
# 4. The load is passed down: all of it to the one support, or to a support whose contact rectangle contains the
#    load's centre (the others get nothing); between two supports it is split by the lever rule (each gets the
#    share of the projection onto the line joining the two contact centres); among more supports the shares
#    solve, in the least-squares sense, the pairwise lever ratios plus "the shares sum to one". A share acts at
#    the centre of its contact rectangle.
# 5. A new box is accepted when it and every box its load reaches pass test 3 with the new loads.
#
# Mass is the box volume: the reference's settings without density give every box density 1. Geometry is taken
# on the 1 cm grid, like the heightmap: a footprint is the block of cells it touches (the reference likewise rounds
# lengths and widths up to whole centimetres), so supports, resting heights and the heightmap always agree.

#: Tops closer than this to a box's resting height support it, cm: half the datasets' 1 mm height resolution,
#: so summed float heights still meet while two distinct dimensions never do.
CONTACT_TOLERANCE_CM = 0.05
#: How far (fraction) the support polygon is pulled towards its vertex mean (the reference's 10 %).
SUPPORT_SHRINK = 0.1
#: The same, for observed states after physics (boxes settle by millimetres): the settle noise Physics Pack itself
#: still calls "in place" (its edge tolerance).
OBSERVED_CONTACT_TOLERANCE_CM = 0.5
_INSIDE_EPS = 1e-9


def cell_rect(x: float, y: float, length: float, width: float) -> tuple[int, int, int, int]:
    """The block of 1 cm cells ``(x0, y0, x1, y1)`` a footprint touches (the heightmap's conservative rule)."""
    return (
        math.floor(x + 1e-6),
        math.floor(y + 1e-6),
        max(math.floor(x + 1e-6) + 1, math.ceil(x + length - 1e-6)),
        max(math.floor(y + 1e-6) + 1, math.ceil(y + width - 1e-6)),
    )


def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (counter-clockwise, no collinear vertices) of 2-D points, as an array."""
    return np.array(_hull_points([(float(p[0]), float(p[1])) for p in points]), dtype=np.float64)


def _hull_points(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Convex hull (counter-clockwise, no collinear vertices) of 2-D points, Andrew's monotone chain."""
    pts = sorted(set(points))
    if len(pts) < 3:
        return pts

    def half(seq: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for p in seq:
            while len(out) >= 2:
                (ax, ay), (bx, by) = out[-2], out[-1]
                if (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax) > _INSIDE_EPS:
                    break
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return lower[:-1] + upper[:-1]


def _inside_shrunk_hull(corners: list[tuple[float, float]], x: float, y: float) -> bool:
    """Whether (x, y) lies strictly inside the support polygon of these contact corners (rule 2), on plain
    floats: the same test as :meth:`_Contacts.holds`, faster for the many small hulls of a whole grid."""
    hull = _hull_points(corners)
    if len(hull) < 3:
        return False
    mx = sum(p[0] for p in hull) / len(hull)
    my = sum(p[1] for p in hull) / len(hull)
    poly = [(px - SUPPORT_SHRINK * (px - mx), py - SUPPORT_SHRINK * (py - my)) for px, py in hull]
    for (ax, ay), (bx, by) in zip(poly, poly[1:] + poly[:1], strict=True):
        if (bx - ax) * (y - ay) - (by - ay) * (x - ax) <= _INSIDE_EPS:
            return False
    return True


def _strictly_inside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Which ``points`` (R, 2) lie strictly inside the counter-clockwise convex ``polygon`` (an edge: outside)."""
    if len(polygon) < 3:
        return np.zeros(len(points), dtype=bool)
    edges = np.roll(polygon, -1, axis=0) - polygon  # (V, 2)
    rel = points[:, None, :] - polygon[None, :, :]  # (R, V, 2)
    cross = edges[None, :, 0] * rel[:, :, 1] - edges[None, :, 1] * rel[:, :, 0]
    inside: np.ndarray = np.all(cross > _INSIDE_EPS, axis=1)
    return inside


def _lstsq_shares(centre: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Shares among three or more supports: pairwise lever ratios and "they sum to one", least squares."""
    k = len(c)
    rows = []
    for i in range(k - 1):
        for j in range(i + 1, k):
            base = c[i] - c[j]
            row = np.zeros(k)
            moment = float((centre - c[i]) @ base)
            if moment != 0:
                row[i], row[j] = 1.0, -abs(float((centre - c[j]) @ base)) / moment
            rows.append(row)
    rows.append(np.ones(k))
    rhs = np.zeros(len(rows))
    rhs[-1] = 1.0
    return np.linalg.lstsq(np.array(rows), rhs, rcond=None)[0]


@dataclass(frozen=True)
class _Contacts:
    """The supports of one box: indices into the placed boxes and the contact rectangles (x0, y0, x1, y1)."""

    support: np.ndarray  # (k,) int
    rects: np.ndarray  # (k, 4)

    @cached_property
    def centres(self) -> np.ndarray:
        centres: np.ndarray = (self.rects[:, :2] + self.rects[:, 2:]) / 2
        return centres

    @cached_property
    def polygon(self) -> np.ndarray:
        """The support polygon (rule 2): the contact hull shrunk towards its vertex mean."""
        r = self.rects
        hull = _hull(np.concatenate([r[:, [0, 1]], r[:, [0, 3]], r[:, [2, 1]], r[:, [2, 3]]]))
        polygon: np.ndarray = hull - SUPPORT_SHRINK * (hull - hull.mean(axis=0))
        return polygon

    def holds(self, points: np.ndarray) -> np.ndarray:
        """Which load centres ``points`` (R, 2) lie strictly inside the support polygon."""
        return _strictly_inside(points, self.polygon)

    def split(self, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """How unit loads centred at ``centres`` (R, 2) pass to the supports (rule 4): shares (R, k) and the
        (x, y) where each share acts (R, k, 2) — the load's own centre when one support takes it all (the only
        one, or the one whose contact holds the centre), otherwise the contact centres."""
        n, k = len(centres), len(self.support)
        whole = np.repeat(centres[:, None, :], k, axis=1)
        if k == 1:
            return np.ones((n, 1)), whole
        r = self.rects
        cx, cy = centres[:, :1], centres[:, 1:]
        direct = (r[:, 0] < cx) & (cx < r[:, 2]) & (r[:, 1] < cy) & (cy < r[:, 3])  # (R, k)
        has = direct.any(axis=1)
        share = np.zeros((n, k))
        at = np.repeat(self.centres[None, :, :], n, axis=0)
        rows = np.flatnonzero(has)
        share[rows, np.argmax(direct[rows], axis=1)] = 1.0
        at[rows] = whole[rows]
        rest = np.flatnonzero(~has)
        c = self.centres
        if k == 2:
            base = (c[0] - c[1]) / float((c[0] - c[1]) @ (c[0] - c[1]))
            share[rest, 0] = np.abs((centres[rest] - c[1]) @ base)
            share[rest, 1] = np.abs((centres[rest] - c[0]) @ base)
        else:
            for row in rest:
                share[row] = _lstsq_shares(centres[row], c)
        return share, at


class SupportModel:
    """The loads of a set of placed boxes under the reference support rule, ready to test new placements.

    Build once per container state (cost grows with the square of the box count, a few ms for 80 boxes), then
    ask :meth:`why_unsupported` / :meth:`supports` for single placements or :meth:`mask` for a whole grid.
    """

    def __init__(self, placed: Sequence[Placement], tolerance: float = CONTACT_TOLERANCE_CM) -> None:
        self.placed = tuple(placed)
        self.tolerance = tolerance
        n = len(self.placed)
        rects = [cell_rect(p.x, p.y, p.length, p.width) for p in self.placed]
        self._rect = np.array(rects, dtype=np.float64).reshape(n, 4)
        self._z = np.array([p.z for p in self.placed], dtype=np.float64)
        self._top = np.array([p.top for p in self.placed], dtype=np.float64)
        centre = (self._rect[:, :2] + self._rect[:, 2:]) / 2
        size = self._rect[:, 2:] - self._rect[:, :2]
        own = size[:, 0] * size[:, 1] * (self._top - self._z)
        self._contacts = [self._contacts_of(r, p.z) for r, p in zip(rects, self.placed, strict=True)]
        self._has_below = np.array([c is not None for c in self._contacts], dtype=bool)
        #: Boxes that rest on others, highest first: the order loads travel down.
        self._order = [int(i) for i in np.argsort(-self._z, kind="stable") if self._contacts[i] is not None]
        # Loads, top-down: each stack's mass and mass-weighted (x, y) centre, and what it passes to its supports.
        self._mass = own.copy()
        self._moment = own[:, None] * centre
        self._passed: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for i in self._order:
            contacts = self._contacts[i]
            assert contacts is not None
            share, at = contacts.split((self._moment[i] / self._mass[i])[None, :])
            mass = share[0] * self._mass[i]
            self._passed[i] = (mass, mass[:, None] * at[0])
            self._mass[contacts.support] += mass
            self._moment[contacts.support] += mass[:, None] * at[0]

    def _contacts_of(self, rect: tuple[int, int, int, int], z: float) -> _Contacts | None:
        """Supports of a cell block resting at ``z`` (None: on the floor or touching nothing at that height)."""
        if z <= self.tolerance or not self.placed:
            return None
        level = np.flatnonzero(np.abs(self._top - z) <= self.tolerance)  # few boxes end at this height
        lo = np.maximum(self._rect[level, :2], rect[:2])
        hi = np.minimum(self._rect[level, 2:], rect[2:])
        touch = np.all(hi > lo, axis=1)
        if not touch.any():
            return None
        return _Contacts(level[touch], np.concatenate([lo[touch], hi[touch]], axis=1))

    def _tipped(self, extra_mass: np.ndarray, extra_moment: np.ndarray) -> np.ndarray:
        """Propagate new loads down (rules 3–5) for a batch of candidates: ``extra_mass`` (P, n) and
        ``extra_moment`` (P, n, 2) hold what each candidate puts on each box. Returns, per candidate, the index
        of the first box that would tip, or -1. Both arrays are consumed."""
        tipped = np.full(len(extra_mass), -1)
        for i in self._order:
            rows = np.flatnonzero((extra_mass[:, i] != 0) & (tipped < 0))
            if rows.size == 0:
                continue
            contacts = self._contacts[i]
            assert contacts is not None
            mass = self._mass[i] + extra_mass[rows, i]
            centre = (self._moment[i] + extra_moment[rows, i]) / mass[:, None]
            inside = contacts.holds(centre)
            tipped[rows[~inside]] = i
            rows, mass, centre = rows[inside], mass[inside], centre[inside]
            share, at = contacts.split(centre)
            passed = share * mass[:, None]
            before_mass, before_moment = self._passed[i]
            cols = contacts.support[None, :]
            extra_mass[rows[:, None], cols] += passed - before_mass
            extra_moment[rows[:, None], cols] += passed[:, :, None] * at - before_moment
        return tipped

    def _load(self, contacts: _Contacts, own: float, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What a new box (own mass, centre) puts on each placed box: (1, n) masses and (1, n, 2) moments."""
        extra_mass = np.zeros((1, len(self.placed)))
        extra_moment = np.zeros((1, len(self.placed), 2))
        share, at = contacts.split(centre[None, :])
        extra_mass[0, contacts.support] = share[0] * own
        extra_moment[0, contacts.support] = (share[0] * own)[:, None] * at[0]
        return extra_mass, extra_moment

    def why_unsupported(
        self, x: float, y: float, length: float, width: float, height: float, z: float
    ) -> str | None:
        """Why a box with this footprint and height resting at ``z`` fails the rule (None: it is supported)."""
        rect = cell_rect(x, y, length, width)
        contacts = self._contacts_of(rect, z)
        if contacts is None:
            return None
        own = (rect[2] - rect[0]) * (rect[3] - rect[1]) * height
        centre = np.array([(rect[0] + rect[2]) / 2, (rect[1] + rect[3]) / 2])
        if not contacts.holds(centre[None, :])[0]:
            return (
                f"its centre ({centre[0]:g}, {centre[1]:g}) cm lies outside the support polygon of the "
                f"{len(contacts.support)} box(es) it rests on at z = {z:g} cm"
            )
        tipped = int(self._tipped(*self._load(contacts, own, centre))[0])
        if tipped < 0:
            return None
        p = self.placed[tipped]
        return f"the box below at ({p.x:g}, {p.y:g}, {p.z:g}) cm would tip: its load centre leaves its support polygon"

    def supports(self, x: float, y: float, length: float, width: float, height: float, z: float) -> bool:
        """Whether the reference rule accepts a box with this footprint and height resting at ``z``."""
        return self.why_unsupported(x, y, length, width, height, z) is None

    def mask(self, z: np.ndarray, length: float, width: float, height: float, fits: np.ndarray) -> np.ndarray:
        """The rule at every integer position: entry [x, y] for the footprint's min corner at (x, y) resting at
        ``z[x, y]``; positions where ``fits`` is False stay False. The same answers as :meth:`supports`, with
        positions grouped by resting height and tested together."""
        out = fits.copy()
        px, py = np.nonzero(fits & (z > self.tolerance))
        if px.size == 0 or not self.placed:
            return out
        lc, wc = cell_rect(0, 0, length, width)[2:]
        own = lc * wc * height
        zs = z[px, py]
        for v in np.unique(zs):
            sel = np.flatnonzero(zs == v)
            level = np.flatnonzero(np.abs(self._top - v) <= self.tolerance)
            if level.size == 0:  # touching nothing at that height: nothing to test (as in the reference)
                continue
            x0, y0 = px[sel][:, None].astype(np.float64), py[sel][:, None].astype(np.float64)
            r = self._rect[level]
            lo = np.stack([np.maximum(r[:, 0], x0), np.maximum(r[:, 1], y0)], axis=2)  # (P, L, 2)
            hi = np.stack([np.minimum(r[:, 2], x0 + lc), np.minimum(r[:, 3], y0 + wc)], axis=2)
            touch = np.all(hi > lo, axis=2)
            count = touch.sum(axis=1)
            centre = np.concatenate([x0 + lc / 2, y0 + wc / 2], axis=1)
            ok = count == 0
            extra_mass = np.zeros((len(sel), len(self.placed)))
            extra_moment = np.zeros((len(sel), len(self.placed), 2))
            one = np.flatnonzero(count == 1)
            if one.size:  # one contact rectangle: the polygon is that rectangle shrunk about its centre
                j = np.argmax(touch[one], axis=1)
                a, b = lo[one, j], hi[one, j]
                ok[one] = np.all(
                    np.abs(centre[one] - (a + b) / 2) < (b - a) / 2 * (1 - SUPPORT_SHRINK), axis=1
                )
                extra_mass[one, level[j]] = own
                extra_moment[one, level[j]] = own * centre[one]
            multi = np.flatnonzero(count > 1)
            for k in multi:  # several contacts: hull by hand (plain floats: these are small and many)
                t = np.flatnonzero(touch[k])
                corners = [
                    (float(a), float(b))
                    for i in t
                    for a in (lo[k, i, 0], hi[k, i, 0])
                    for b in (lo[k, i, 1], hi[k, i, 1])
                ]
                ok[k] = _inside_shrunk_hull(corners, float(centre[k, 0]), float(centre[k, 1]))
            deep_multi = multi[ok[multi] & (touch[multi] & self._has_below[level]).any(axis=1)]
            for k in deep_multi:
                t = touch[k]
                contacts = _Contacts(level[t], np.concatenate([lo[k, t], hi[k, t]], axis=1))
                extra_mass[k : k + 1], extra_moment[k : k + 1] = self._load(contacts, own, centre[k])
            deep = np.flatnonzero(ok & (touch & self._has_below[level]).any(axis=1))
            if deep.size:
                ok[deep] = self._tipped(extra_mass[deep], extra_moment[deep]) < 0
            out[px[sel], py[sel]] = ok
        return out


def is_supported(
    placed: Sequence[Placement], candidate: Placement, tolerance: float = CONTACT_TOLERANCE_CM
) -> bool:
    """Whether ``candidate`` (resting at its ``z``) is stable on ``placed`` under the reference support rule.

    For many candidates on one state, build a :class:`SupportModel` once and call its ``supports``.
    """
    c = candidate
    return SupportModel(placed, tolerance).supports(c.x, c.y, c.length, c.width, c.height, c.z)


def check_support(placed: Sequence[Placement], candidate: Placement) -> Infeasible | None:
    """:func:`is_supported` with the reason: ``Infeasible("unsupported", ...)`` or None."""
    c = candidate
    why = SupportModel(placed).why_unsupported(c.x, c.y, c.length, c.width, c.height, c.z)
    return None if why is None else Infeasible("unsupported", f"unsupported placement: {why}")
