"""The records a board travels as, from the engine (or a from-scratch computation) to the publisher and the views.

A :class:`Board` or :class:`Grid` is typed: its head (what every page repeats), its lists of rows, and what only
the engine's own consumers read (each view's column tops, the all-entries view as arrays, what the grid needs of
a board) as named fields — never keys of a dict that a serialiser must know to skip. Its *rows* (an entry of a
board, a row of the grid) are :data:`Row`: the JSON object a page serves, as it is served (a typed object per
row would be converted back for every serialisation, 150,000 of them a publication at 10,000 submissions).
A row's keys starting with ``_`` or ``best_`` are never served (:func:`robobpp.boards.ranking.served_fields`).
"""

from __future__ import annotations

import dataclasses
from collections import UserList
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from robobpp.scoring import stats
from robobpp.scoring.metrics import metrics_for
from robobpp.scoring.scores import ANCHORS_VERSION, RANKED_BY, WEIGHTS
from robobpp.vocabulary import CLOSED

K = TypeVar("K")
#: A board's entry or a grid's row, as a page serves it (with its ``_`` keys, which it does not).
Row = dict[str, Any]
#: Each view's (``best``, ``all``) column tops: the best distinct values a page of that view highlights.
Tops = dict[str, dict[str, list[float]]]


@dataclass(frozen=True, slots=True)
class RankedView:
    """A board's (or the grid's) all-entries view as arrays, as the board engine hands it out beside the
    entries (:attr:`Board.ranked`): what publishing and the grid need without building a ranked dict per
    entry — an arriving entry moves the rank of everyone below it, and nothing else of theirs.

    ``ids``, ``ranks``: rank order. ``ids_by_column`` (ascending) and ``rank_by_column``: by column (a board's
    ranked entries in submission order; the grid's complete rows). ``row(column)``: that column's row
    without ranks, built on demand; ``serials``: a number per column that changes whenever that row does
    (the publisher serialises a row again only then; the grid compares them as arrays). ``cells``: the
    grid's cell ranks, rank order × boards."""

    ids: np.ndarray
    ranks: np.ndarray
    ids_by_column: np.ndarray
    rank_by_column: np.ndarray
    serials: np.ndarray
    row: Callable[[int], Row]
    cells: np.ndarray | None = None


class Positions(Mapping[int, int]):
    """Each ranked submission's position in a board's rank order, read off its arrays (the board engine's
    :attr:`Board.index`): 16 bytes an entry where a dict took about 100."""

    def __init__(self, ids_by_column: np.ndarray, order: np.ndarray) -> None:
        self._ids = ids_by_column  # ascending
        self._position = np.empty(len(order), dtype=np.int64)
        self._position[order] = np.arange(len(order))

    def __getitem__(self, submission_id: int) -> int:
        at = int(np.searchsorted(self._ids, submission_id))
        if at >= len(self._ids) or self._ids[at] != submission_id:
            raise KeyError(submission_id)
        return int(self._position[at])

    def __iter__(self) -> Iterator[int]:
        return iter(self._ids.tolist())

    def __len__(self) -> int:
        return len(self._ids)


class LazyRows(UserList[Row]):
    """A list built on first use: the board engine's ranked entries (or grid rows) as dicts with their ranks,
    which only the pages of a small deployment and the tests read (publishing uses the :class:`RankedView`)."""

    def __init__(self, build: Callable[[], list[Row]] | Iterable[Row] = ()) -> None:
        #: how to build UserList's ``data`` on first use (a slice or copy of a built one is built at once)
        self._build: Callable[[], list[Row]] | None = build if callable(build) else None
        self._data: list[Row] = [] if callable(build) else list(build)

    @property
    def data(self) -> list[Row]:
        if self._build is not None:
            self._data, self._build = self._build(), None
        return self._data

    @data.setter
    def data(self, value: list[Row]) -> None:
        self._data, self._build = value, None


@dataclass(frozen=True, slots=True)
class ForGrid:
    """What the overall grid needs of a board and nothing else does: its entries' score and stable score by
    ``_column`` (2 × entries), and — a from-scratch board only; the engine's grid computes its own — the grid's
    resamples of both, a row per entry by ``_column`` (entries × ``GRID_RESAMPLES``, float32)."""

    by_column: np.ndarray
    samples: np.ndarray | None = None
    stable_samples: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class Board:
    """One board: its ranked entries in rank order, the unranked ones, each participant's best ranked among
    them (the default view), and what its pages and its track's grid read.

    ``loop``: how its runs were played (:data:`robobpp.vocabulary.Loop`; served as ``protocol``, the API's name
    for it). ``lookaheads``: the track's lookaheads with boards, once the board is part of a track's set
    (None: a board computed alone). ``index``: each ranked submission's position in ``entries``. ``ranked``: the all-entries
    view as arrays (the board engine's; None: read it off ``entries``). ``for_grid``: None once handed out.
    Frozen: a board handed out never changes (the engine makes a new one; its rows are never changed either)."""

    dataset: str
    setting: str
    track: str
    groups: int
    entries: Sequence[Row]
    unranked: list[Row]
    best: list[Row]
    index: Mapping[int, int]
    tops: Tops
    loop: str = CLOSED
    lookahead: int = 0
    lookaheads: list[int] | None = None
    ranked: RankedView | None = None
    for_grid: ForGrid | None = None

    def head(self) -> dict[str, Any]:
        """What every page of the board repeats (its rules: metrics, weights, resamples and confidence)."""
        head: dict[str, Any] = {
            "dataset": self.dataset,
            "setting": self.setting,
            "track": self.track,
            "metrics": [m.key for m in metrics_for(self.setting)],
            "weights": WEIGHTS[self.setting],
            "ranked_by": RANKED_BY,
            "anchors": ANCHORS_VERSION,
            "groups": self.groups,
            "resamples": stats.RESAMPLES,
            "confidence": stats.CONFIDENCE,
            "protocol": self.loop,
            "lookahead": self.lookahead,
        }
        if self.lookaheads is not None:
            head["lookaheads"] = self.lookaheads
        return head

    def served(self) -> Board:
        """The board as handed out: without what only its track's grid reads (tens of MB at 10,000 entries)."""
        return dataclasses.replace(self, for_grid=None)

    def grid_inputs(self) -> ForGrid:
        if self.for_grid is None:
            raise ValueError(
                f"the {self.setting}/{self.dataset} board was handed out without its grid inputs"
            )
        return self.for_grid


@dataclass(frozen=True, slots=True)
class Grid:
    """The overall grid: the rows of submissions ranked on every board (rank order; the Mean ranks them),
    the rows apart (ranked on fewer boards, or failed), and each participant's best of both."""

    datasets: list[str]
    settings: list[str]
    track: str
    rows: Sequence[Row]
    apart: list[Row]
    best: list[Row]
    best_apart: list[Row]
    tops: Tops
    loop: str = CLOSED
    lookahead: int = 0
    lookaheads: list[int] | None = None
    ranked: RankedView | None = None

    @property
    def keys(self) -> list[str]:
        """Its boards (``setting/dataset``), in the order of its columns and of the stored cell ranks."""
        return [f"{s}/{d}" for s in self.settings for d in self.datasets]

    def head(self) -> dict[str, Any]:
        head: dict[str, Any] = {
            "datasets": self.datasets,
            "settings": self.settings,
            "track": self.track,
            "boards": len(self.datasets) * len(self.settings),
            "ranked_by": RANKED_BY,
            "protocol": self.loop,
            "lookahead": self.lookahead,
        }
        if self.lookaheads is not None:
            head["lookaheads"] = self.lookaheads
        return head

    def served(self) -> Grid:
        """The grid as handed out: itself (nothing of it is for the engine alone)."""
        return self


#: What a track's engine hands out: its boards and grids by key.
Published = Board | Grid


def as_board(item: Published) -> Board:
    """``item``, which must be a board (a key of a board was looked up)."""
    if not isinstance(item, Board):
        raise TypeError(f"a grid where a board was expected ({item.track}, {item.loop}, {item.lookahead})")
    return item


def as_grid(item: Published) -> Grid:
    """``item``, which must be a grid."""
    if not isinstance(item, Grid):
        raise TypeError(f"a board where a grid was expected ({item.setting}/{item.dataset})")
    return item


def empty_tops(keys: Sequence[str]) -> Tops:
    return {view: {key: [] for key in keys} for view in ("best", "all")}


def with_lookaheads(items: dict[K, Published], keys: Iterable[K], lookaheads: list[int]) -> None:
    """Name the track's lookaheads on the boards and grids of ``keys`` (every one says which its track has)."""
    for key in keys:
        items[key] = dataclasses.replace(items[key], lookaheads=lookaheads)
