"""The lookup attack on evaluation groups: what the public data tells about the rest of a group.

A policy sees each box's size and mass (``robobpp/1``'s ``BoxModel``) as the episode goes. Every split's pool
ships in the public data, so an attacker can search the boxes shown so far as a run of consecutive boxes in
every public sequence (each dataset's train and test pool, in pool order) and, where every match continues the
same way, know the rest of the group. :func:`lookup` plays that attacker on one group, box by box; the private
set must give it nothing (tests/datasets/test_lookup.py, docs/datasets.md "Private groups nobody can look up").
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from robobpp.core import Box
from robobpp.datasets.pool import load_pool
from robobpp.datasets.registry import DATASETS

#: Marks the end of each public sequence in the index (no box has this id), so no match runs across two.
_END = -1
#: The id of a shown box that appears in no public sequence (matches nothing).
_UNKNOWN = -2


@dataclass(frozen=True)
class Lookup:
    """What the attacker learned on one group of ``boxes`` boxes."""

    boxes: int
    #: Boxes shown when every public match first continued exactly as the group does (None: never).
    told_after: int | None
    #: The longest prefix of the group that is a run of some public sequence (0: not even its first box).
    matched_prefix: int


class PublicIndex:
    """Every public sequence as one array of box ids, ready for prefix searches."""

    def __init__(self, sequences: Iterable[np.ndarray]) -> None:
        tables = [np.asarray(t, dtype=float).reshape(-1, 4) for t in sequences]
        if not tables:
            raise ValueError("no public sequence to search")
        distinct, ids = np.unique(np.concatenate(tables), axis=0, return_inverse=True)
        self._ids = {tuple(row): i for i, row in enumerate(distinct.tolist())}
        ids = ids.ravel()
        parts, offset = [], 0
        for t in tables:
            parts += [ids[offset : offset + len(t)], np.array([_END])]
            offset += len(t)
        self._seq = np.concatenate(parts)

    def encode(self, boxes: Sequence[Box] | np.ndarray) -> np.ndarray:
        """Ids of boxes given as :class:`Box` or rows ``length, width, height, mass``."""
        rows = [(b.length, b.width, b.height, b.mass) if isinstance(b, Box) else tuple(b) for b in boxes]
        return np.array([self._ids.get(tuple(float(v) for v in r), _UNKNOWN) for r in rows], dtype=np.int64)

    def lookup(self, boxes: Sequence[Box] | np.ndarray) -> Lookup:
        """Show the group's boxes one by one; after each, is the rest told by every public match alike?"""
        group = self.encode(boxes)
        n = len(group)
        # Padded so a continuation that runs past the end of the index reads _END (never a box).
        seq = np.r_[self._seq, np.full(n, _END)]
        matches = np.flatnonzero(seq[: len(self._seq)] == group[0])
        shown = 0
        while len(matches) and shown < n - 1:
            shown += 1
            rest = seq[matches[:, None] + np.arange(shown, n)]
            if np.all(rest == group[shown:]):
                return Lookup(n, shown, shown)
            matches = matches[seq[matches + shown] == group[shown]]
        return Lookup(n, None, shown + 1 if len(matches) else shown)


def public_index(root: Path | None = None) -> PublicIndex:
    """The index of every public pool: each dataset's train and test split, boxes as a policy sees them."""
    tables = []
    for name, spec in DATASETS.items():
        for split in spec.splits:
            pool = load_pool(name, split, root=root)
            tables.append(np.column_stack([pool.dims, pool.masses]))
    return PublicIndex(tables)
