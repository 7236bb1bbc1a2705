"""Vectorised placement candidates on the heightmap, shared by the heightmap-based policies.

Feasible means what the environment accepts, in every setting, as the reference's does: inside the container and
below its height (``CandidateMap.fits``). The paper's heuristics choose among exactly these: the reference scores
them without any support test, and its heuristic figures are reproduced that way (docs/baselines.md).

The reference support rule (:class:`robobpp.core.feasibility.SupportModel`) is extra information a policy may use.
:func:`support_model` gives it for the observed state — the rule on a physical state (boxes observed after physics
carry their attitude, ``Placement.quaternion``; Math Pack's never do), no rule on a Math Pack state — as the
reference's PCT environment applies it to its leaf nodes in Physics and Execution Pack only. PCT's leaves use it
(:mod:`robobpp.policies.pct.leaves`), and the Gym env offers it as a second mask (``info["support_mask"]``). It is
a per-position test, so it is applied lazily: :meth:`CandidateMap.supported` tests one position,
:attr:`CandidateMap.support_mask` every position, only when asked.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from robobpp.core import Action, Observation, Placement, drop_height_map
from robobpp.core.feasibility import OBSERVED_CONTACT_TOLERANCE_CM, SupportModel
from robobpp.core.feasible_grid import orientation_fits
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
    """For one orientation: feasibility and resting height of every integer position (x, y).

    ``fits`` says the box with its min corner at (x, y) cm stays inside the container (bounds are implied by
    the map's shape): what the environment accepts. ``z[x, y]`` is where its bottom would rest, computed when
    first read (the env's mask needs ``fits`` only). ``support_mask`` adds the support rule of the observed state.
    """

    orientation: int
    length: float
    width: float
    height: float
    fits: np.ndarray
    #: The observed boxes; the support rule over them is built only when asked (:attr:`support`): the paper
    #: heuristics never ask, so their decisions don't pay for it.
    placed: tuple[Placement, ...]
    #: The observed heightmap the resting heights are read from.
    heightmap: np.ndarray

    @cached_property
    def z(self) -> np.ndarray:
        """Resting height of the box's bottom at every position (same shape as ``fits``)."""
        return drop_height_map(self.heightmap, self.length, self.width)

    @cached_property
    def support(self) -> SupportModel:
        """The support rule of the observed state (shared by every map of that state)."""
        return _support_model(self.placed)

    def supported(self, x: int, y: int) -> bool:
        """Whether the support rule accepts the box at (x, y) (bounds are not re-checked)."""
        return self.support.supports(x, y, self.length, self.width, self.height, float(self.z[x, y]))

    @cached_property
    def support_mask(self) -> np.ndarray:
        """``fits`` and supported, for every position (equal to ``fits`` on a Math Pack state)."""
        return self.support.mask(self.z, self.length, self.width, self.height, self.fits)


def candidate_maps(obs: Observation) -> Iterator[CandidateMap]:
    """One :class:`CandidateMap` per allowed orientation (skipping ones where the box cannot fit at all)."""
    placed = tuple(obs.placed)
    for orientation, (length, width, height), fits in orientation_fits(
        obs.heightmap, obs.box, obs.container, obs.orientations
    ):
        yield CandidateMap(orientation, length, width, height, fits, placed, obs.heightmap)


def first_placement(
    ranked: Sequence[int] | np.ndarray, xs: np.ndarray, ys: np.ndarray, orientations: np.ndarray
) -> Action | None:
    """The first candidate of ``ranked`` (indices into the parallel arrays), or None when there is none.

    Every candidate must already fit the container; the reference scores only such placements and keeps the
    best, which is the first in score order. This is the paper heuristics' choice in every setting.
    """
    if len(ranked) == 0:
        return None
    k = int(ranked[0])
    return Action(float(xs[k]), float(ys[k]), int(orientations[k]))


def argmin_placement(
    obs: Observation,
    score: Callable[[CandidateMap, np.ndarray, np.ndarray], np.ndarray],
    allowed: Callable[[CandidateMap, np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> Action | None:
    """The position and orientation of least ``score(cand, xs, ys)`` over every candidate map's ``fits``.

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
        parts.append((cost, px, py, np.full(len(px), cand.orientation)))
    if not parts:
        return None
    cost, px, py, po = (np.concatenate(c) for c in zip(*parts, strict=True))
    return first_placement(np.lexsort((po, py, px, cost)), px, py, po)


def unrotated_range(obs: Observation) -> Callable[[CandidateMap, np.ndarray, np.ndarray], np.ndarray]:
    """The reference's position range for DBL and HM: ``x ≤ L − l`` and ``y ≤ W − w`` with the box's
    orientation-0 footprint ``l × w``, in every orientation (its loops bound x and y before turning the box)."""
    nx, ny = obs.heightmap.shape
    lc, wc = cells_spanned(obs.box.length), cells_spanned(obs.box.width)

    def allowed(cand: CandidateMap, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        fits: np.ndarray = (xs <= nx - lc) & (ys <= ny - wc)
        return fits

    return allowed
