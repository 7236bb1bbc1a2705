"""The candidate set every policy sees: bounds and height (what the environment accepts, in every setting, as the
reference's), and the reference support rule as extra information on states observed after physics (the
reference's PCT applies it to its leaves in Physics and Execution Pack; its heuristics never do)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from robobpp.core import SupportModel
from robobpp.core.feasibility import TOLERANCE_CM
from robobpp.policies import load_policy
from robobpp.policies.candidates import candidate_maps, support_model
from tests.policies.scenes import scene

#: The paper's seven heuristics and the two rule-based policies that are not in the paper.
HEURISTICS = ("dbl", "hm", "lsah", "onlinebph", "br", "macs", "sdfpack", "packe-rules", "random")


def test_fits_keeps_unsupported_positions_and_the_support_mask_drops_them() -> None:
    # a 4 × 10 × 5 block at the back. A 10 × 10 × 1 slab at x < 4 rests on it with contact [x, 4] and centre
    # x + 5 > 4: never inside, so the rule refuses every raised position; the floor beyond the block (x ≥ 4) is
    # fine. The environment accepts them all (bounds and height only).
    obs = scene((20, 10, 10), [(0, 0, 4, 10, 5)], (10, 10, 1), physical=True)
    cand = next(c for c in candidate_maps(obs) if c.orientation == 0)
    raised = cand.z > 0
    assert raised.any() and cand.fits[raised].all()
    assert not cand.support_mask[raised].any()
    assert cand.support_mask[~raised].all()
    # the same scene as a Math Pack state: no rule, the support mask is the fits mask
    math = next(
        c for c in candidate_maps(scene((20, 10, 10), [(0, 0, 4, 10, 5)], (10, 10, 1))) if c.orientation == 0
    )
    np.testing.assert_array_equal(math.support_mask, math.fits)


def test_fits_is_the_resting_height_below_the_container_top() -> None:
    """``fits`` is computed without the resting heights (``window_all``); it says what they say, in every
    orientation (tests/core/test_heightmap.py checks the function itself on many states)."""
    rng = np.random.default_rng(5)
    placed = [
        (int(rng.integers(0, 12)), int(rng.integers(0, 8)), 6, 4, float(rng.integers(1, 4))) for _ in range(8)
    ]
    obs = scene((18, 12, 9), placed, (5.5, 3.2, 4.1))
    maps = list(candidate_maps(obs))
    assert len(maps) == 2
    for cand in maps:
        expected = cand.z + cand.height <= obs.container.height + TOLERANCE_CM
        assert expected.any() and not expected.all()
        np.testing.assert_array_equal(cand.fits, expected)


def test_support_mask_agrees_with_the_support_model_everywhere() -> None:
    rng = np.random.default_rng(3)
    placed = [
        (int(rng.integers(0, 12)), int(rng.integers(0, 8)), 6, 4, float(rng.integers(1, 4))) for _ in range(8)
    ]
    obs = scene((18, 12, 30), placed, (5, 3, 2), physical=True)
    model = support_model(obs)
    for cand in candidate_maps(obs):
        for x, y in np.argwhere(cand.fits):
            expected = model.supports(
                int(x), int(y), cand.length, cand.width, cand.height, float(cand.z[x, y])
            )
            assert bool(cand.support_mask[x, y]) is expected


def test_dbl_takes_the_cheapest_position_even_unsupported() -> None:
    # a 2-wide block at the back and a lower one (top 3) beside it: the 10 × 10 slab rests at z = 5 on the
    # narrow block alone, its centre 5 outside [0.1, 1.9]: no position is supported. The reference's DBL
    # applies no support rule (its environment accepts what fits), so DBL places it at (0, 0), and gravity
    # decides. (Physics version 3 applied the rule here and ended the episode: no feasible placement.)
    lone = scene((10, 10, 20), [(0, 0, 2, 10, 5), (4, 0, 6, 10, 3)], (10, 10, 1), physical=True)
    assert not SupportModel(lone.placed).supports(0, 0, 10, 10, 1, 5.0)
    action = load_policy("dbl").act(lone)
    assert action is not None and (action.x, action.y) == (0, 0)


@pytest.mark.parametrize("name", HEURISTICS)
def test_a_heuristic_chooses_on_a_physical_state_as_on_the_same_math_pack_state(name: str) -> None:
    # scenes where the support rule refuses the heuristic's first choice or every raised position: the
    # heuristics ignore it in every setting, so the observed attitudes change nothing
    scenes = [
        ((10, 10, 20), [(0, 0, 2, 10, 5), (4, 0, 6, 10, 3)], (10, 10, 1)),
        ((8, 2, 10), [(0, 0, 2, 2, 3), (4, 0, 4, 2, 3)], (4, 2, 1)),
        ((20, 10, 10), [(0, 0, 4, 10, 5), (4, 0, 3, 3, 2)], (10, 6, 1)),
    ]
    refused = 0
    for container, placed, box in scenes:
        math, physical = scene(container, placed, box), scene(container, placed, box, physical=True)
        chosen = load_policy(name).act(math)
        assert chosen is not None
        assert load_policy(name).act(physical) == chosen
        length, width, height = physical.box.dims(chosen.orientation)
        z = next(c for c in candidate_maps(physical) if c.orientation == chosen.orientation).z[
            int(chosen.x), int(chosen.y)
        ]
        refused += not support_model(physical).supports(chosen.x, chosen.y, length, width, height, float(z))
    assert refused >= 1  # the rule would have changed at least one of these choices


def test_math_pack_states_have_no_rule_and_physical_states_the_looser_one() -> None:
    math = scene((10, 10, 20), [(0, 0, 2, 10, 5), (4, 0, 6, 10, 3)], (10, 10, 1))
    assert support_model(math).supports(0, 0, 10, 10, 1, 5.0)
    settled = dataclasses.replace(
        math, placed=tuple(dataclasses.replace(p, quaternion=(0.0, 0.0, 0.0, 1.0)) for p in math.placed)
    )
    assert not support_model(settled).supports(0, 0, 10, 10, 1, 5.0)
