import numpy as np
import pytest

from robobpp.core import (
    Box,
    ContainerSpec,
    Placement,
    SupportModel,
    check_action,
    check_support,
    is_supported,
)

C = ContainerSpec(10, 8, 5)
B = Box(4, 2, 3)


def test_inside_is_feasible():
    assert check_action(0, 0, 0, B, C) is None
    assert check_action(6, 6, 0, B, C) is None  # touching the far walls exactly
    assert check_action(8, 4, 1, B, C) is None  # rotated: 2 along x, 4 along y


@pytest.mark.parametrize(
    ("x", "y", "o", "reason"),
    [
        (7, 0, 0, "out_of_bounds"),  # 7 + 4 > 10
        (0, 5, 1, "out_of_bounds"),  # rotated: 5 + 4 > 8
        (-0.5, 0, 0, "out_of_bounds"),
        (float("nan"), 0, 0, "invalid_action"),
        (0, float("inf"), 0, "invalid_action"),
        (0, 0, 2, "invalid_action"),
        (0, 0, True, "invalid_action"),
        ("1", 0, 0, "invalid_action"),
        (0, None, 0, "invalid_action"),
    ],
)
def test_refusals_name_the_reason(x, y, o, reason):
    result = check_action(x, y, o, B, C)
    assert result is not None and result.reason == reason and result.detail


def test_height_is_checked_when_resting_height_known():
    assert check_action(0, 0, 0, B, C, z=2) is None  # top at 5 == height
    refused = check_action(0, 0, 0, B, C, z=2.5)
    assert refused is not None and refused.reason == "too_high"


# --- the reference support rule -------------------------------------------------------------------------------


def _stack(*boxes: tuple[float, float, float, float, float, float]) -> list[Placement]:
    """(x, y, z, length, width, height) → placements in that order."""
    return [Placement(*b, 0, k) for k, b in enumerate(boxes)]


BASE = (0, 0, 0, 10, 10, 5)


def test_a_box_on_the_floor_needs_no_support() -> None:
    assert is_supported([], Placement(3, 3, 0, 4, 4, 4, 0, 0))
    assert is_supported(_stack(BASE), Placement(12, 0, 0, 4, 4, 4, 0, 1))


@pytest.mark.parametrize(
    ("x", "ok"),
    [
        (0, True),  # fully on the base
        (4, True),  # contact x ∈ [4, 10], shrunk 10 % → [4.3, 9.7]; centre 9 inside
        (5, False),  # contact [5, 10] shrunk → [5.25, 9.75]; centre 10 outside
        (6, False),  # centre 11 beyond the base altogether
    ],
)
def test_overhang_is_refused_once_the_centre_leaves_the_shrunk_contact(x: int, ok: bool) -> None:
    # worked out by hand: footprint 10 wide, centre at x + 5, contact rectangle [x, 10] × [0, 10]
    assert is_supported(_stack(BASE), Placement(x, 0, 5, 10, 10, 2, 0, 1)) is ok


def test_a_bridge_over_two_columns_is_supported_by_their_hull() -> None:
    columns = _stack((0, 0, 0, 4, 10, 5), (6, 0, 0, 4, 10, 5))
    # contacts [0, 4] and [6, 10]: their hull spans the gap, the centre (5, 5) lies inside it
    assert is_supported(columns, Placement(0, 0, 5, 10, 10, 2, 0, 2))
    # resting on one column only, centre at 3 + 5 = 8 over [6, 10] shrunk [6.2, 9.8]: fine; at 7: 12 > 9.8
    assert is_supported(columns, Placement(3, 0, 5, 10, 10, 2, 0, 2))
    assert not is_supported(columns, Placement(7, 0, 5, 10, 10, 2, 0, 2))


def test_a_load_that_tips_the_box_below_is_refused() -> None:
    # B (12 × 10 × 2, mass 240) rests on A over x ∈ [2, 10] (shrunk [2.8, 9.2]); its centre x = 8 is inside.
    placed = _stack(BASE, (2, 0, 5, 12, 10, 2))
    assert SupportModel(placed).why_unsupported(0, 0, 1, 1, 1, 0) is None
    # C (4 × 10 × 10, mass 400) sits wholly on B's overhang at x ∈ [10, 14]: C itself is fine (centre 12 in
    # [10.2, 13.8]), but B's load centre moves to (240·8 + 400·12) / 640 = 10.5 > 9.2: B tips.
    why = SupportModel(placed).why_unsupported(10, 0, 4, 10, 10, 7)
    assert why is not None and "below" in why
    # a light C (height 1, mass 40) moves it only to (1920 + 480) / 280 ≈ 8.57: accepted
    assert SupportModel(placed).supports(10, 0, 4, 10, 1, 7)


def test_load_goes_to_the_support_under_it_then_by_the_lever_rule() -> None:
    columns = _stack((0, 0, 0, 4, 10, 5), (6, 0, 0, 4, 10, 5), (0, 0, 5, 10, 10, 2))
    model = SupportModel(columns)
    # the bridge's centre (5, 5) is over neither contact: split by the lever rule between x = 2 and x = 8 → ½, ½
    passed = model._passed[2]
    assert passed[0] == pytest.approx([100.0, 100.0])
    # a box on the bridge over the right column pulls the bridge's load centre into that contact: all of it there
    assert model.supports(6, 0, 4, 10, 10, 7)


def test_only_tops_at_the_resting_height_support() -> None:
    # two boxes under the footprint, 5 and 3 cm tall: resting at 5, only the taller one touches
    placed = _stack((0, 0, 0, 4, 10, 5), (6, 0, 0, 4, 10, 3))
    assert not is_supported(placed, Placement(0, 0, 5, 10, 10, 2, 0, 2))  # centre 5 outside [0.2, 3.8]


def test_check_support_names_the_reason() -> None:
    refused = check_support(_stack(BASE), Placement(6, 0, 5, 10, 10, 2, 0, 1))
    assert (
        refused is not None
        and refused.reason == "unsupported"
        and "outside the support polygon" in refused.detail
    )
    assert check_support(_stack(BASE), Placement(0, 0, 5, 10, 10, 2, 0, 1)) is None


def test_math_pack_accepts_an_unsupported_placement_like_the_reference() -> None:
    """packsim's Math Pack runs with the stability check off; the paper's Math figures are reproduced that way."""
    from robobpp.core import Action
    from robobpp.episode import run_episode
    from robobpp.policies import BasePolicy
    from tests.conftest import make_spec

    class Scripted(BasePolicy):
        def __init__(self, answers: list[Action]) -> None:
            self.answers = answers

        def act(self, obs):
            return self.answers.pop(0)

    spec = make_spec([(4, 10, 5), (10, 10, 2), (4, 10, 5)], container=(10, 10, 20))
    # the second box hangs 6 cm past the first one (centre 5 over contact [0, 4]): placed anyway, at z = 5
    result = run_episode(spec, Scripted([Action(0, 0, 0), Action(0, 0, 0), Action(6, 0, 0)]), "math")
    assert result.termination == "completed" and result.boxes_placed == 3
    assert result.steps[1].placement is not None and result.steps[1].placement["z"] == 5


def test_physics_pack_lets_physics_decide_an_unsupported_placement() -> None:
    """Physics and Execution Pack do not refuse a placement the rule rejects either (the reference's env step
    checks only bounds and height); gravity decides. There the rule is in the candidates policies see."""
    from robobpp.core import Action
    from robobpp.episode import run_episode
    from robobpp.policies import BasePolicy
    from tests.conftest import make_spec

    class Scripted(BasePolicy):
        def __init__(self, answers: list[Action]) -> None:
            self.answers = answers

        def act(self, obs):
            return self.answers.pop(0)

    spec = make_spec([(4, 10, 5), (10, 10, 2)], container=(20, 10, 20))
    result = run_episode(spec, Scripted([Action(0, 0, 0), Action(0, 0, 0)]), "physics")
    assert result.steps[1].placement is not None and result.termination != "unsupported"


def test_observed_states_after_physics_use_the_looser_contact_tolerance() -> None:
    from robobpp.core import Observation
    from robobpp.policies.candidates import support_model

    # two blocks whose tops settled 0.3 cm apart: as an observed (physics) state both carry the slab
    settled = (
        Placement(0, 0, 0, 4, 10, 5.0, 0, 0, (0.0, 0.0, 0.0, 1.0)),
        Placement(6, 0, 0, 4, 10, 4.7, 0, 1, (0.0, 0.0, 0.0, 1.0)),
    )
    obs = Observation("o", 2, ContainerSpec(10, 10, 20), settled, np.zeros((10, 10)), Box(10, 10, 2))
    assert support_model(obs).supports(0, 0, 10, 10, 2, 5.0)
    # the same geometry as an exact (Math Pack) state: only the 5 cm block touches, the centre is outside
    exact = [Placement(p.x, p.y, p.z, p.length, p.width, p.height, 0, p.index) for p in settled]
    assert not is_supported(exact, Placement(0, 0, 5, 10, 10, 2, 0, 2))
