"""Stored parts decoded many at a time give what decoding each alone gives, and a part table keeps them alike."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from robobpp.scoring.entries import FORMAT, EntryPart, PartTable, StoredParts, entry_part


def _part(rng: np.random.Generator, setting: str, ids: list[int]) -> EntryPart:
    n = len(ids)
    values = {
        "space_utilization": rng.random(n).tolist(),
        "occupancy": [None, *rng.random(n - 1).tolist()],
        "decision_time": (0.01 * rng.random(n)).tolist(),
        "local_stability": rng.random(n).tolist(),
        "static_stability": rng.random(n).tolist(),
        "trajectory_length": rng.random(n).tolist(),
    }
    pooled = {
        "collapsed_placement": [[float(rng.integers(0, 5)), 40.0] for _ in range(n)],
        "dangerous_operation": [[float(rng.integers(0, 3)), float(rng.integers(1, 50))] for _ in range(n)],
    }
    return entry_part({"ids": ids, "values": values, "pooled": pooled}, setting)


def _same(a: EntryPart | None, b: EntryPart | None) -> bool:
    if a is None or b is None:
        return a is b
    return (
        a.setting == b.setting
        and np.array_equal(a.ids, b.ids)
        and np.array_equal(a.top, b.top)
        and np.array_equal(a.bottom, b.bottom)
        and np.array_equal(a.metric_ci, b.metric_ci, equal_nan=True)
        and a.stable_ci == b.stable_ci
        and a.seed == b.seed
    )


@pytest.mark.parametrize("setting", ["math", "physics", "execution"])
def test_many_decoded_at_once_equal_each_decoded_alone(setting: str) -> None:
    rng = np.random.default_rng(7)
    ten, other = list(range(10)), [0, 2, 3, 5, 8, 9, 11, 12, 13, 20]  # two group-id lists of one length
    parts = {sid: _part(rng, setting, ten if sid % 4 else other) for sid in range(1, 41)}
    encoded = {sid: p.encode() for sid, p in parts.items()}
    data: dict[int, bytes | None] = dict(encoded)
    data[41] = None  # no stored part
    data[42] = b"RB"  # too short to be one
    data[43] = encoded[1][:4] + (FORMAT - 1).to_bytes(2, "little") + encoded[1][6:]  # an older format
    data[44] = encoded[2] + b"\0" * 8  # longer than this version writes: still read, alone
    wrong = "math" if setting != "math" else "physics"
    data[45] = _part(rng, wrong, ten).encode()  # another setting's metrics
    sids = [*data, 3]  # the 3rd given twice: its last is kept
    blobs = [*data.values(), parts[7].encode()]
    decoded, undecoded = StoredParts.decode(setting, sids, blobs)
    assert [sids[k] for k in undecoded] == [41, 42, 43, 45]
    assert len(decoded.rows) == 2  # the two group-id lists of the forty
    assert set(decoded) == set(range(1, 41)) | {44} and len(decoded) == 41
    for sid in range(1, 41):
        alone = EntryPart.decode(encoded[sid], setting) if sid != 3 else parts[7]
        assert _same(decoded[sid], alone)
        assert decoded.ids_of(sid) == np.array(ten if sid % 4 else other, dtype=np.int64).tobytes()
    assert _same(decoded[44], parts[2])
    decoded.set(45, None)
    decoded.set(5, parts[6])  # set again: its decoded row is no longer its part
    assert decoded[45] is None and decoded.ids_of(45) is None
    assert _same(decoded[5], parts[6]) and 45 in decoded and 46 not in decoded


def test_a_table_keeps_decoded_rows_as_it_keeps_parts_given_one_by_one() -> None:
    rng = np.random.default_rng(8)
    setting = "execution"
    parts = {sid: _part(rng, setting, list(range(12))) for sid in range(1, 31)}
    decoded, _ = StoredParts.decode(setting, list(parts), [p.encode() for p in parts.values()])
    replaced = dataclasses.replace(parts[4], seed=parts[4].seed + 1)
    decoded.set(4, replaced)  # set again after decoding
    decoded.set(9, None)  # no figures any more
    expected = {sid: p for sid, p in parts.items() if sid != 9} | {4: replaced}

    by_rows, one_by_one = PartTable(setting), PartTable(setting)
    by_rows.put(9, parts[9])  # had a part: forgotten by the None
    by_rows.put(2, parts[3])  # had another part: replaced
    by_rows.put_many(decoded)
    one_by_one.put_many(expected)
    assert 9 not in by_rows and len(by_rows) == len(expected)
    sids = sorted(expected)
    for table in (by_rows, one_by_one):
        top, bottom = table.stacked(sids)
        assert np.array_equal(top, np.stack([expected[s].top for s in sids]))
        assert np.array_equal(bottom, np.stack([expected[s].bottom for s in sids]))
        assert table.seeds(sids).tolist() == [expected[s].seed for s in sids]
        metric, stable = table.intervals_of(sids)
        for k, s in enumerate(sids):
            assert np.array_equal(metric[k], expected[s].metric_ci, equal_nan=True)
            assert tuple(stable[k]) == expected[s].stable_ci
