"""Each baseline's rule on a small scene where its choice can be worked out by hand."""

from __future__ import annotations

import pytest

from robobpp.core import Action
from robobpp.policies import load_policy
from robobpp.policies.sdfpack import SDFPack
from tests.policies.scenes import scene


def act(name: str, obs) -> Action | None:
    return load_policy(name).act(obs)


def where(action: Action | None) -> tuple[float, float, int] | None:
    return None if action is None else (action.x, action.y, action.orientation)


def test_dbl_goes_lowest_then_back_left() -> None:
    # a 4×4×5 box in the back-left corner: the floor beside it at (0, 4) and (4, 0) ties on x + y = 4;
    # the smaller x wins. On top of it (z = 5) would cost 500.
    obs = scene((10, 10, 10), [(0, 0, 4, 4, 5)], (2, 2, 1))
    assert where(act("dbl", obs)) == (0, 4, 0)


def test_hm_picks_the_least_added_heightmap_volume() -> None:
    # terrain along x: [3, 3, 0, 0, 3, 3, 3, 3] (width 2). A 4×2×1 box rests at z = 3 everywhere; at x = 0 or
    # 2 it traps 2·2·3 = 12 cm³ under itself, at x = 4 nothing. DBL wants the smallest x at that z, but at
    # x = 0 the box rests on [0, 2] alone with its centre at 2, outside the shrunk contact [0.1, 1.9]: the
    # support rule refuses it. At x = 1 the contacts [1, 2] and [4, 5] span its centre 3: DBL takes x = 1.
    obs = scene((8, 2, 10), [(0, 0, 2, 2, 3), (4, 0, 4, 2, 3)], (4, 2, 1))
    assert where(act("hm", obs)) == (4, 0, 0)
    assert where(act("dbl", obs)) == (1, 0, 0)


def test_hm_breaks_ties_back_left() -> None:
    assert where(act("hm", scene((10, 10, 10), [], (3, 2, 1)))) == (0, 0, 0)


def test_lsah_minimises_the_bounding_box_surface() -> None:
    # a 5×5×5 cube in the corner of a 10×10×10 container; a 5×5×2 slab on top makes a 5×5×7 bounding box
    # (area 190), beside it a 10×5×5 one (area 250): LSAH stacks, DBL goes to the floor.
    obs = scene((10, 10, 10), [(0, 0, 5, 5, 5)], (5, 5, 2))
    assert where(act("lsah", obs)) == (0, 0, 0)
    assert where(act("dbl", obs)) == (0, 5, 0)


def test_lsah_rotates_when_that_keeps_the_box_smaller() -> None:
    # a 5×2×5 box: beside the cube along x unrotated gives 10×5×5 (250); rotated (2×5) gives 7×5×5 (190),
    # the same as unrotated in front (5×7×5); ties go to z, then x + y, then the smaller x: (0, 5) unrotated.
    obs = scene((10, 10, 10), [(0, 0, 5, 5, 5)], (5, 2, 5))
    assert where(act("lsah", obs)) == (0, 5, 0)


def test_onlinebph_takes_the_first_feasible_space_lowest_first() -> None:
    # a 5×10×5 wall at x = 0: the floor space is x ∈ [5, 10) (5 wide), the space on top spans everything at z = 5.
    wall = [(0, 0, 5, 10, 5)]
    # 6×3: unrotated it is too long for the floor space, rotated (3×6) it fits → first space, orientation 1
    assert where(act("onlinebph", scene((10, 10, 10), wall, (6, 3, 2)))) == (5, 0, 1)
    # 6×6 fits the floor space in neither orientation → the next space, on top of the wall
    assert where(act("onlinebph", scene((10, 10, 10), wall, (6, 6, 2)))) == (0, 0, 0)


def test_br_prefers_the_space_the_box_fills() -> None:
    # walls at x ∈ [0, 3) and [5, 10), height 5, leave a 2-wide slot. A 2×10×5 board fills the slot
    # (fit 1, the same board still fits above it, top 5/10: utility 1.5); on top it would cover 20 % of the
    # space (fit 0.2, still fits beside it, top 10/10: utility 0.2).
    obs = scene((10, 10, 10), [(0, 0, 3, 10, 5), (5, 0, 5, 10, 5)], (2, 10, 5))
    assert where(act("br", obs)) == (3, 0, 0)


def test_macs_keeps_the_largest_free_rectangle() -> None:
    # a 2×2×5 block at x ∈ [5, 7) of a 10×2×10 container: floor slots of 5 and 3 cells. A 2×2×5 box in the
    # small slot keeps the 5-cell slot (area 10) below z = 5; in the big slot only 3 cells (area 6) stay.
    # Above z = 5 everything is free either way. DBL would take x = 0.
    obs = scene((10, 2, 10), [(5, 0, 2, 2, 5)], (2, 2, 5))
    assert where(act("macs", obs)) == (7, 0, 0)
    assert where(act("dbl", obs)) == (0, 0, 0)


def test_sdfpack_fills_the_snug_slot_and_scores_it_by_hand() -> None:
    # two 4×10×2 walls leave a 2-wide slot at x ∈ [4, 6). A 2×3×2 box at its back end touches a wall on
    # three faces and the floor; only its front face (+y) sees open space up to the truncation τ = 6.
    obs = scene((10, 10, 10), [(0, 0, 4, 10, 2), (6, 0, 4, 10, 2)], (2, 3, 2))
    assert where(act("sdfpack", obs)) == (4, 0, 0)
    policy = SDFPack()
    from robobpp.policies.ems import EmsTracker, ems_candidates

    cands = ems_candidates(obs, EmsTracker().update(obs.heightmap, 10.0), corners=4)
    slot = [k for k in range(len(cands)) if (cands.x[k], cands.y[k], cands.orientation[k]) == (4, 0, 0)]
    cost = policy.sdf_cost(obs.heightmap, cands.take(slot))
    # 1 face of 4 × (8 × 4) side samples at distance τ, out of 4·32 side + 64 bottom samples
    assert cost[0] == pytest.approx(32 / (4 * 32 + 64))


def test_packe_rules_takes_the_candidate_with_the_lowest_top() -> None:
    # a 4×4×6 block in the corner: first fit and column building give (0, 0) on top (top 8), floor building
    # and the extreme points give (0, 4) and (4, 0) on the floor (top 2); x + y ties, the smaller x wins.
    obs = scene((10, 10, 10), [(0, 0, 4, 4, 6)], (3, 3, 2))
    assert where(act("packe-rules", obs)) == (0, 4, 0)


def test_packe_rules_only_uses_its_generators() -> None:
    # a 2-high 3×10 step at x ∈ [2, 5) on a 10-long floor: a 2×10×1 box fits the floor at x = 0 (first fit,
    # floor building) — the lowest top there is 1.
    obs = scene((10, 10, 10), [(2, 0, 3, 10, 2)], (2, 10, 1))
    assert where(act("packe-rules", obs)) == (0, 0, 0)
