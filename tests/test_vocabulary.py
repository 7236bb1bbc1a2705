"""The vocabulary: each word's tuple is its Literal's values, and the rules about loops read as documented."""

from __future__ import annotations

from typing import get_args

import pytest

from robobpp import vocabulary as V


@pytest.mark.parametrize(
    ("values", "literal"),
    [
        (V.DATASETS, V.DatasetName),
        (V.SETTINGS, V.SettingName),
        (V.LOOPS, V.Loop),
        (V.TRACKS, V.Track),
        (V.BOARD_TRACKS, V.BoardTrack),
        (V.SUBMISSION_STATUSES, V.SubmissionStatus),
        (V.EPISODE_STATUSES, V.EpisodeStatus),
    ],
)
def test_each_tuple_is_its_literal(values: tuple[str, ...], literal: object) -> None:
    assert values == get_args(literal)


def test_the_subsets_are_of_their_words() -> None:
    assert set(V.PHYSICAL) < set(V.SETTINGS) and V.MATH in V.SETTINGS
    assert set(V.BOARD_TRACKS) < set(V.TRACKS)
    assert set(V.ACTIVE_SUBMISSION) < set(V.SUBMISSION_STATUSES)
    assert set(V.QUEUED_EPISODE) | set(V.TERMINAL_EPISODE) == set(V.EPISODE_STATUSES)
    assert (V.CLOSED, V.PAPER) == V.LOOPS


def test_a_math_pack_board_is_the_closed_loops() -> None:
    assert V.board_loop("math", V.PAPER) == V.CLOSED
    assert V.board_loop("physics", V.PAPER) == V.PAPER
    assert V.board_loop("execution", V.CLOSED) == V.CLOSED


def test_a_lookahead_has_closed_loop_boards_only() -> None:
    assert V.has_boards(V.PAPER, 0) and V.has_boards(V.PAPER, 0, "physics")
    assert V.has_boards(V.CLOSED, 3) and V.has_boards(V.CLOSED, 3, "physics")
    assert V.has_boards(V.PAPER, 3, "math")  # the closed loop's board
    assert not V.has_boards(V.PAPER, 3, "physics")
    assert not V.has_boards(V.PAPER, 3)  # the paper loop's grid
