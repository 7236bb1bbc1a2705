"""How user-facing text names a box of an episode (termination details)."""

from __future__ import annotations

from robobpp.core import box_label


def test_box_label_gives_the_index_and_the_place_in_the_sequence() -> None:
    """ "box 37" beside "38 / 80 boxes placed" read as an off-by-one: the index and its ordinal, together."""
    assert box_label(37) == "box #37 (the 38th)"
    assert [box_label(i).split("the ")[1] for i in (0, 1, 2, 3, 10, 11, 12, 20, 21, 100, 110)] == [
        "1st)",
        "2nd)",
        "3rd)",
        "4th)",
        "11th)",
        "12th)",
        "13th)",
        "21st)",
        "22nd)",
        "101st)",
        "111th)",
    ]
