import pytest

from robobpp.core import Box, ContainerSpec, check_action

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
