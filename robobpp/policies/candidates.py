"""Vectorised placement candidates on the heightmap, shared by the heightmap-based policies.

Feasible means what the reference environment accepts: inside the container, below its height, and — in the
physical settings — supported (:class:`robobpp.core.feasibility.SupportModel`). The reference (packsim) turns its
stability check on for Physics and Execution Pack and off for Math Pack; a policy sees which from the state: boxes
observed after physics carry their attitude (``Placement.quaternion``), Math Pack's never do. Bounds and height are
cheap whole-grid arrays (``fits``); the support rule is a per-position test, so it is applied lazily: :func:`first_supported` walks a ranking until a
supported placement turns up, and :attr:`CandidateMap.feasible` tests every position only when asked (the Gym
env's action mask).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from robobpp.core import Action, Observation, Placement, drop_height_map
from robobpp.core.feasibility import (
    OBSERVED_CONTACT_TOLERANCE_CM,
    TOLERANCE_CM,
    SupportModel,
)
from robobpp.core.heightmap import cells_spanned


class _NoSupportRule(SupportModel):
    """Math Pack: every placement inside the container is accepted (the reference's check is off there)."""

    def __init__(self) -> None:
        super().__init__(())

    def why_unsupported(self, *args: float) -> str | None:
        return None

    def mask(self, z: np.ndarray, length: float, width: float, height: float, fits: np.ndarray) -> np.ndarray:
        return fits.copy()


_NO_RULE = _NoSupportRule()


def physical(placed: Sequence[Placement]) -> bool:
    """Whether a state was observed after physics (its boxes carry attitudes): the support rule applies."""
    return any(p.quaternion is not None for p in placed)


@lru_cache(maxsize=4)
def _support_model(placed: tuple[Placement, ...]) -> SupportModel:
    # After physics, tops are off by the settle noise, so contacts are looser than on exact geometry.
    return SupportModel(placed, OBSERVED_CONTACT_TOLERANCE_CM) if physical(placed) else _NO_RULE


def support_model(obs: Observation) -> SupportModel:
    """The support rule over the observed boxes (built once per state, shared by every caller); a rule that
    accepts everything for a Math Pack state."""
    return _support_model(tuple(obs.placed))


@dataclass(frozen=True)
class CandidateMap:
    """For one orientation: resting height and feasibility of every integer position (x, y).

    ``z[x, y]`` is where the box's bottom would rest with its min corner at (x, y) cm; ``fits`` says the box
    then stays inside the container (bounds are implied by the map's shape); ``feasible`` adds the support rule.
    """

    orientation: int
    length: float
    width: float
    height: float
    z: np.ndarray
    fits: np.ndarray
    support: SupportModel

    def supported(self, x: int, y: int) -> bool:
        """Whether the support rule accepts the box at (x, y) (bounds are not re-checked)."""
        return self.support.supports(x, y, self.length, self.width, self.height, float(self.z[x, y]))

    @cached_property
    def feasible(self) -> np.ndarray:
        """``fits`` and supported, for every position."""
        return self.support.mask(self.z, self.length, self.width, self.height, self.fits)


def candidate_maps(obs: Observation) -> Iterator[CandidateMap]:
    """One :class:`CandidateMap` per allowed orientation (skipping ones where the box cannot fit at all)."""
    limit = obs.container.height + TOLERANCE_CM
    support = support_model(obs)
    for orientation in obs.orientations:
        length, width, height = obs.box.dims(orientation)
        if length > obs.container.length + TOLERANCE_CM or width > obs.container.width + TOLERANCE_CM:
            continue
        z = drop_height_map(obs.heightmap, length, width)
        if z.size == 0:
            continue
        yield CandidateMap(orientation, length, width, height, z, z + height <= limit, support)


def first_supported_index(
    obs: Observation,
    ranked: Sequence[int] | np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    orientations: np.ndarray,
    zs: np.ndarray,
) -> int | None:
    """The first index of ``ranked`` (into the parallel arrays) whose placement the support rule accepts."""
    support = support_model(obs)
    for k in ranked:
        length, width, height = obs.box.dims(int(orientations[k]))
        if support.supports(float(xs[k]), float(ys[k]), length, width, height, float(zs[k])):
            return int(k)
    return None


def first_supported(
    obs: Observation,
    ranked: Sequence[int] | np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    orientations: np.ndarray,
    zs: np.ndarray,
) -> Action | None:
    """The first candidate of ``ranked`` (indices into the parallel arrays) that the support rule accepts.

    Every candidate must already fit the container; the reference scores only feasible placements and keeps
    the best, which is the first feasible one in score order.
    """
    k = first_supported_index(obs, ranked, xs, ys, orientations, zs)
    return None if k is None else Action(float(xs[k]), float(ys[k]), int(orientations[k]))


def argmin_placement(
    obs: Observation,
    score: Callable[[CandidateMap, np.ndarray, np.ndarray], np.ndarray],
    allowed: Callable[[CandidateMap, np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> Action | None:
    """The feasible position and orientation of least ``score(cand, xs, ys)`` over every candidate map.

    ``xs``/``ys`` are broadcastable column/row index arrays of the map's positions; ``allowed`` (same
    arguments) narrows the positions searched. Ties go as in the reference's loops (x outer, then y, then
    orientation): the smaller x, then the smaller y, then the earlier orientation. ``None`` when no position
    is feasible in any orientation.
    """
    parts: list[tuple[np.ndarray, ...]] = []
    for cand in candidate_maps(obs):
        nx, ny = cand.z.shape
        xs, ys = np.arange(nx)[:, None], np.arange(ny)[None, :]
        ok = cand.fits if allowed is None else cand.fits & allowed(cand, xs, ys)
        px, py = np.nonzero(ok)
        cost = np.broadcast_to(score(cand, xs, ys), ok.shape)[px, py]
        parts.append((cost, px, py, np.full(len(px), cand.orientation), cand.z[px, py]))
    if not parts:
        return None
    cost, px, py, po, pz = (np.concatenate(c) for c in zip(*parts, strict=True))
    ranked = np.lexsort((po, py, px, cost))
    return first_supported(obs, ranked, px, py, po, pz)


def unrotated_range(obs: Observation) -> Callable[[CandidateMap, np.ndarray, np.ndarray], np.ndarray]:
    """The reference's position range for DBL and HM: ``x ≤ L − l`` and ``y ≤ W − w`` with the box's
    orientation-0 footprint ``l × w``, in every orientation (its loops bound x and y before turning the box)."""
    nx, ny = obs.heightmap.shape
    lc, wc = cells_spanned(obs.box.length), cells_spanned(obs.box.width)

    def allowed(cand: CandidateMap, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        return (xs <= nx - lc) & (ys <= ny - wc)

    return allowed
