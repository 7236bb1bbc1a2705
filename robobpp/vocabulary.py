"""The benchmark's words, declared once: datasets, settings, tracks, loops and statuses.

Each word is a ``Literal`` type (what mypy and the API's schemas check) and a tuple of its values in the
order tables show them (what code iterates and validates against), so a new value is added in one place.
The strings are the ones stored in the database and sent over the JSON API: renaming a value here is a
migration and an API change, not a refactoring.

"Protocol" means only the wire protocol ``robobpp/1`` (:mod:`robobpp.protocol`). How a physical setting's
episode is played — closed loop, or the paper's plan replayed open loop (docs/benchmark.md, "Two
protocols") — is its *loop*: :data:`Loop`. The stored column and the API field keep their name
``protocol`` (the database and clients already speak it).

This module imports nothing: every layer may use it.
"""

from __future__ import annotations

from typing import Final, Literal, get_args

#: The datasets, in the paper's order (its tables, the grid's columns).
DatasetName = Literal["repetitive", "diverse", "longboard"]
DATASETS: Final[tuple[DatasetName, ...]] = get_args(DatasetName)

#: The settings (test environments), in the paper's order: geometry, physics, the robot.
SettingName = Literal["math", "physics", "execution"]
SETTINGS: Final[tuple[SettingName, ...]] = get_args(SettingName)
MATH: Final = "math"
#: The settings with a simulator (metrics of stability, the paper's replay).
PHYSICAL: Final[tuple[SettingName, ...]] = ("physics", "execution")

#: How a physical setting's episode is played (docs/benchmark.md, "Two protocols"): ``closed``, the policy
#: observes the setting's state at every step (the benchmark); ``paper``, its Math Pack actions replayed
#: open loop in the setting, as the paper did (:mod:`robobpp.replay`). In Math Pack both are one episode.
Loop = Literal["closed", "paper"]
LOOPS: Final[tuple[Loop, ...]] = get_args(Loop)
CLOSED: Final = "closed"
PAPER: Final = "paper"

#: What a submission is evaluated on: the private test split (the boards), the public train groups
#: (debugging, boards of their own) or the private pool's hold-out draw (verifications; docs/server.md).
Track = Literal["private", "public", "verify"]
TRACKS: Final[tuple[Track, ...]] = get_args(Track)
#: The tracks with boards, that a participant submits to (a verification is the admin's).
BoardTrack = Literal["private", "public"]
BOARD_TRACKS: Final[tuple[BoardTrack, ...]] = get_args(BoardTrack)

#: An entry's standing on a board: ranked, or shown apart and never ranked (``partial``: it ran fewer groups
#: than the board's other entries; ``failed``: too many of its episodes ended in a policy failure;
#: docs/benchmark.md, "Who is ranked").
EntryStatus = Literal["ranked", "partial", "failed"]
UnrankedStatus = Literal["partial", "failed"]

#: A submission's life: ``queued → running → completed | failed | cancelled``.
SubmissionStatus = Literal["queued", "running", "completed", "failed", "cancelled"]
SUBMISSION_STATUSES: Final[tuple[SubmissionStatus, ...]] = get_args(SubmissionStatus)
#: The submissions still being evaluated.
ACTIVE_SUBMISSION: Final[tuple[SubmissionStatus, ...]] = ("queued", "running")

#: An episode's life: ``pending → running → done | failed | cancelled``. ``waiting``: a paper-loop replay
#: whose Math Pack episode has not finished yet (nothing to replay); it becomes ``pending`` (or ``failed``)
#: in the transaction that records that Math episode.
EpisodeStatus = Literal["waiting", "pending", "running", "done", "failed", "cancelled"]
EPISODE_STATUSES: Final[tuple[EpisodeStatus, ...]] = get_args(EpisodeStatus)
#: The episodes still in the queue (to be played, or being played).
QUEUED_EPISODE: Final[tuple[EpisodeStatus, ...]] = ("waiting", "pending", "running")
#: The episodes that will not change again.
TERMINAL_EPISODE: Final[tuple[EpisodeStatus, ...]] = ("done", "failed", "cancelled")


def board_loop(setting: str, loop: str) -> Loop:
    """The loop whose runs a board of ``setting`` shows: in Math Pack both loops are the same (closed)
    episodes, so a Math Pack board is the closed loop's."""
    return PAPER if loop == PAPER and setting in PHYSICAL else CLOSED


def has_boards(loop: str, lookahead: int, setting: str | None = None) -> bool:
    """Whether a lookahead has boards under ``loop`` (of ``setting``; None: the overall grid): a lookahead
    K > 0 has closed-loop boards only, the paper's tables having been made without lookahead (a Math Pack
    board is closed loop under both; docs/server.md, "Boards per lookahead")."""
    return not lookahead or (board_loop(setting, loop) if setting is not None else loop) == CLOSED


__all__ = [
    "ACTIVE_SUBMISSION",
    "BOARD_TRACKS",
    "CLOSED",
    "DATASETS",
    "EPISODE_STATUSES",
    "LOOPS",
    "MATH",
    "PAPER",
    "PHYSICAL",
    "QUEUED_EPISODE",
    "SETTINGS",
    "SUBMISSION_STATUSES",
    "TERMINAL_EPISODE",
    "TRACKS",
    "BoardTrack",
    "DatasetName",
    "EntryStatus",
    "EpisodeStatus",
    "Loop",
    "SettingName",
    "SubmissionStatus",
    "Track",
    "UnrankedStatus",
    "board_loop",
    "has_boards",
]
