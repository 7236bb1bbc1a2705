"""The candidate set every policy sees: bounds, height and, on states observed after physics, the reference
support rule (the reference's Math Pack has it off)."""

from __future__ import annotations

import numpy as np

from robobpp.core import SupportModel
from robobpp.policies import load_policy
from robobpp.policies.candidates import candidate_maps, support_model
from tests.policies.scenes import scene


def test_feasible_mask_drops_unsupported_positions() -> None:
    # a 4 × 10 × 5 block at the back. A 10 × 10 × 1 slab at x < 4 rests on it with contact [x, 4] and centre
    # x + 5 > 4: never inside, so every raised position is refused; the floor beyond the block (x ≥ 4) is fine
    obs = scene((20, 10, 10), [(0, 0, 4, 10, 5)], (10, 10, 1), physical=True)
    cand = next(c for c in candidate_maps(obs) if c.orientation == 0)
    raised = cand.z > 0
    assert raised.any() and cand.fits[raised].all()
    assert not cand.feasible[raised].any()
    assert cand.feasible[~raised].all()


def test_mask_agrees_with_the_support_model_everywhere() -> None:
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
            assert bool(cand.feasible[x, y]) is expected


def test_dbl_takes_the_cheapest_supported_position() -> None:
    # an 8 × 10 × 5 block leaves the floor strip x ∈ [8, 10). A 6 × 10 box cannot reach the floor, so it rests
    # at z = 5; (0, 0) has contact [0, 6] (shrunk [0.3, 5.7]) and centre 3: supported, and the cheapest.
    obs = scene((10, 10, 20), [(0, 0, 8, 10, 5)], (6, 10, 1), physical=True)
    action = load_policy("dbl").act(obs)
    assert action is not None and (action.x, action.y) == (0, 0)
    # a 2-wide block at the back and a lower one (top 3) beside it: the 10 × 10 slab rests at z = 5 on the
    # narrow block alone, its centre 5 outside [0.1, 1.9]. Without support DBL would take (0, 0); now nothing.
    lone = scene((10, 10, 20), [(0, 0, 2, 10, 5), (4, 0, 6, 10, 3)], (10, 10, 1), physical=True)
    assert not SupportModel(lone.placed).supports(0, 0, 10, 10, 1, 5.0)
    assert load_policy("dbl").act(lone) is None
    # the same scene as a Math Pack state: no support rule, DBL takes the cheapest position (0, 0)
    math = scene((10, 10, 20), [(0, 0, 2, 10, 5), (4, 0, 6, 10, 3)], (10, 10, 1))
    action = load_policy("dbl").act(math)
    assert action is not None and (action.x, action.y) == (0, 0)
