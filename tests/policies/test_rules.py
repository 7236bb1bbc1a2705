"""Each baseline's rule on a small scene where its choice can be worked out by hand."""

from __future__ import annotations

import pytest

from robobpp.core import Action
from robobpp.policies import load_policy
from robobpp.policies.candidates import support_model
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
    # 2 it traps 2·2·3 = 12 cm³ under itself, at x = 4 nothing. DBL takes x = 0 (same z, smaller x).
    obs = scene((8, 2, 10), [(0, 0, 2, 2, 3), (4, 0, 4, 2, 3)], (4, 2, 1))
    assert where(act("hm", obs)) == (4, 0, 0)
    assert where(act("dbl", obs)) == (0, 0, 0)
    # after physics the choice is the same: the reference's heuristics apply no support rule in any setting
    # (at x = 0 the box rests on [0, 2] alone, its centre 2 outside the shrunk contact [0.1, 1.9]; the rule
    # would move it to x = 1, where the contacts [1, 2] and [4, 5] span its centre 3)
    physical = scene((8, 2, 10), [(0, 0, 2, 2, 3), (4, 0, 4, 2, 3)], (4, 2, 1), physical=True)
    assert where(act("dbl", physical)) == (0, 0, 0)
    assert not support_model(physical).supports(0, 0, 4, 2, 1, 3.0)
    assert support_model(physical).supports(1, 0, 4, 2, 1, 3.0)


def test_hm_breaks_ties_back_left() -> None:
    assert where(act("hm", scene((10, 10, 10), [], (3, 2, 1)))) == (0, 0, 0)


def test_lsah_scores_the_bounding_rectangle_and_the_candidates_own_top() -> None:
    # a 5×5×5 cube in the corner of 10×10×10; a 5×5×2 box. Candidates are space corners: (5, 0) and (0, 5)
    # on the floor, (0, 0) on the cube. Score X·Y + (z + h)·(X + Y) over the packed footprint rectangle:
    # (5, 0): 10·5 + 2·15 = 80; (0, 5): 5·10 + 2·15 = 80; (0, 0) on top: 5·5 + 7·10 = 95.
    # The floor ties; both spaces leave zero slack along one axis, so back-left decides: (0, 5).
    obs = scene((10, 10, 10), [(0, 0, 5, 5, 5)], (5, 5, 2))
    assert where(act("lsah", obs)) == (0, 5, 0)


def test_lsah_height_term_is_the_candidates_top_not_the_stack() -> None:
    # a 5×5×8 tower: beside it 10·5 + 1·15 = 65, on it 5·5 + 9·10 = 115. (With the stack's top, 8, in the
    # height term the floor would score 50 + 8·15 = 170 and LSAH would climb the tower.)
    obs = scene((10, 10, 10), [(0, 0, 5, 5, 8)], (5, 5, 1))
    assert where(act("lsah", obs)) == (0, 5, 0)


def test_onlinebph_sorts_spaces_by_height_then_y_then_x() -> None:
    # a 5×5×5 cube at the origin leaves floor spaces with corners (5, 0) and (0, 5): (z, y, x) order takes
    # (5, 0) first (y = 0); the old (z, x, y) order would have taken (0, 5).
    obs = scene((10, 10, 10), [(0, 0, 5, 5, 5)], (2, 2, 1))
    assert where(act("onlinebph", obs)) == (5, 0, 0)
    # a 5×10×5 wall: the floor space's corner is (5, 0); 6×3 is too long there unrotated, rotated it fits
    wall = [(0, 0, 5, 10, 5)]
    assert where(act("onlinebph", scene((10, 10, 10), wall, (6, 3, 2)))) == (5, 0, 1)
    # 6×6 fits there in neither orientation → the next space, the wall's top: resting on [0, 5] × [0, 6] with
    # its centre (3, 3) inside the shrunk contact
    assert where(act("onlinebph", scene((10, 10, 10), wall, (6, 6, 2)))) == (0, 0, 0)


def test_onlinebph_skips_spaces_narrower_than_the_smallest_item_side() -> None:
    # walls 4 and 5 wide, 5 high, leave a 1 cm floor strip at x ∈ [4, 5): its corner (4, 0) comes first in
    # (z, y, x) order, and a 3×3×2 box dropped there would rest on the second wall at z = 5. The strip is
    # narrower than the smallest item side seen (2), so, as the reference's EMS do, it is not listed: the
    # next space is the one over both walls, corner (0, 0).
    obs = scene((10, 10, 10), [(0, 0, 4, 10, 5), (5, 0, 5, 10, 5)], (3, 3, 2))
    assert where(act("onlinebph", obs)) == (0, 0, 0)
    # a 1×3×2 box is 1 cm thin: the strip is usable again and it goes into it, on the floor
    walls = [(0, 0, 4, 10, 5), (5, 0, 5, 10, 5)]
    assert where(act("onlinebph", scene((10, 10, 10), walls, (1, 3, 2)))) == (4, 0, 0)


def test_br_takes_the_largest_space() -> None:
    # walls at x ∈ [0, 3) and [5, 10), 5 high, in 10×10×10: the slot [3, 5) × [0, 10) × [0, 10) holds 200 cm³,
    # the space over everything [0, 10)² × [5, 10) 500 cm³. A 2×10×5 board fits both (the one item type fits
    # both: +1 +10 each), so BR puts it at the big space's corner, on the first wall (fully supported).
    obs = scene((10, 10, 10), [(0, 0, 3, 10, 5), (5, 0, 5, 10, 5)], (2, 10, 5))
    assert where(act("br", obs)) == (0, 0, 0)


def test_macs_counts_levels_below_where_the_box_rests() -> None:
    # 10×2×10: block A 2×2×5 at x ∈ [0, 2), block B 2×2×3 at x ∈ [8, 10); a 2×2×1 box. On the floor the
    # score is 0 (no level below). On B (z = 3): levels 0–2 keep [2, 8) free → 3 · 12 = 36. On A (z = 5):
    # levels 0–2 keep [2, 8) (12), levels 3–4 keep [2, 10) (16, B is only 3 high) → 36 + 32 = 68. MACS
    # climbs onto A; DBL stays on the floor.
    obs = scene((10, 2, 10), [(0, 0, 2, 2, 5), (8, 0, 2, 2, 3)], (2, 2, 1))
    assert where(act("macs", obs)) == (0, 0, 0)
    assert where(act("dbl", obs)) == (2, 0, 0)


def test_sdfpack_stacks_near_the_corner_rather_than_far_on_the_floor() -> None:
    # a 10×10×2 platform in the corner of 20×20×20; a 2×2×2 box has one sample point, its min corner, and
    # scores its distance from the origin corner + 0.01·z: on the platform at (0, 0) 2 + 0.02 = 2.02, on the
    # floor at best (10, 0) or (0, 10): 10. SDFPack climbs; DBL (100·z first) stays on the floor.
    obs = scene((20, 20, 20), [(0, 0, 10, 10, 2)], (2, 2, 2))
    assert where(act("sdfpack", obs)) == (0, 0, 0)
    assert where(act("dbl", obs)) == (0, 10, 0)


def test_sdfpack_searches_every_second_centimetre() -> None:
    # a 3×10×5 wall at x ∈ [0, 3): the floor starts at x = 3, which the 2 cm grid (x = 0, 2, 4, …) skips.
    # At x = 2 the 2×2×2 box rests on the wall: √(2² + 5²) + 0.05 = 5.44; at x = 4 on the floor: 4.
    obs = scene((10, 10, 10), [(0, 0, 3, 10, 5)], (2, 2, 2))
    assert where(act("sdfpack", obs)) == (4, 0, 0)
    assert where(act("dbl", obs)) == (3, 0, 0)


def test_sdfpack_sums_the_distance_of_every_5_cm_sample_point() -> None:
    import numpy as np

    from robobpp.policies.sdfpack import distance_sum, sample_offsets

    # a 6×6×6 box at the origin: sample offsets {0, 5} on each axis, 8 points at distances 0, 5 (×3),
    # 5√2 (×3), 5√3
    offsets = sample_offsets(6, 6, 6)
    assert [list(o) for o in offsets] == [[0, 5], [0, 5], [0, 5]]
    zero = np.zeros(1)
    assert distance_sum(zero, zero, zero, offsets)[0] == pytest.approx(15 + 15 * 2**0.5 + 5 * 3**0.5)
    # at (2, 0, 1) a 4.5 cm high box (one level of points, x offsets 0 and 5 of its 6 cm): √5 + √50
    got = distance_sum(np.array([2.0]), zero, np.array([1.0]), sample_offsets(6, 2, 4.5))[0]
    assert got == pytest.approx(5**0.5 + 50**0.5)


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
