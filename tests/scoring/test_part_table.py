"""The board's columnar store of entry parts gives back each part's sum terms and weights bit for bit."""

from __future__ import annotations

import numpy as np

from robobpp.scoring.entries import EntryPart, IdIndex, PartTable, entry_part


def _part(rng: np.random.Generator, setting: str, groups: int, holes: bool) -> EntryPart:
    values = {
        "space_utilization": rng.random(groups).tolist(),
        "occupancy": rng.random(groups).tolist(),
        "decision_time": (0.01 * rng.random(groups)).tolist(),
        "local_stability": rng.random(groups).tolist(),
        "static_stability": rng.random(groups).tolist(),
        "trajectory_length": rng.random(groups).tolist(),
    }
    if holes:
        values["occupancy"][1] = None
        values["static_stability"][0] = None
    pooled = {
        "collapsed_placement": [[float(rng.integers(0, 5)), 40.0] for _ in range(groups)],
        "dangerous_operation": [
            [float(rng.integers(0, 3)), float(rng.integers(0, 50))] for _ in range(groups)
        ],
    }
    return entry_part({"ids": list(range(groups)), "values": values, "pooled": pooled}, setting)


def test_parts_come_back_bit_for_bit() -> None:
    rng = np.random.default_rng(1)
    for setting in ("math", "physics", "execution"):
        table = PartTable(setting)
        parts = {sid: _part(rng, setting, 6, holes=sid % 3 == 0) for sid in range(1, 40)}
        table.put_many({sid: p for sid, p in parts.items() if sid < 30})
        for sid in range(30, 40):
            table.put(sid, parts[sid])
        for sid in (2, 5, 31):  # freed rows are reused
            table.drop(sid)
        table.put(2, parts[2])
        sids = [s for s in parts if s not in (5, 31)]
        top, bottom = table.stacked(sids)
        assert np.array_equal(top, np.stack([parts[s].top for s in sids]))
        assert np.array_equal(bottom, np.stack([parts[s].bottom for s in sids]))
        metric_all, stable_all = table.intervals_of(sids)
        assert table.seeds(sids).tolist() == [parts[s].seed for s in sids]
        for k, s in enumerate(sids):
            assert np.array_equal(metric_all[k], parts[s].metric_ci, equal_nan=True)
            assert tuple(stable_all[k]) == parts[s].stable_ci
        other = _part(rng, setting, 5, holes=False)  # another group-id list: another block
        table.put(99, other)
        metric_two, stable_two = table.intervals_of([99, sids[0]])
        assert np.array_equal(metric_two[0], other.metric_ci, equal_nan=True)
        assert np.array_equal(metric_two[1], parts[sids[0]].metric_ci, equal_nan=True)
        assert tuple(stable_two[0]) == other.stable_ci


def test_a_part_the_nan_cannot_say_keeps_its_weights() -> None:
    rng = np.random.default_rng(2)
    table = PartTable("math")
    plain = _part(rng, "math", 4, holes=False)
    odd = EntryPart("math", plain.ids, plain.top, plain.bottom * 0.5, plain.metric_ci, plain.stable_ci, 7)
    table.put(1, plain)
    table.put(2, odd)
    top, bottom = table.stacked([1, 2])
    assert np.array_equal(bottom, np.stack([plain.bottom, odd.bottom]))
    assert np.array_equal(top, np.stack([plain.top, odd.top]))


def test_entries_are_found_replaced_and_dropped_many_at_a_time() -> None:
    """The table finds entries by id in sorted arrays: ids in any order, replaced parts moving to another
    block, ids it never had, and a block emptied and made again."""
    rng = np.random.default_rng(3)
    table = PartTable("physics")
    six = {sid: _part(rng, "physics", 6, holes=sid % 2 == 0) for sid in (50, 7, 31, 12, 99, 3)}
    table.put_many(six)
    assert len(table) == 6
    assert table.contains([3, 4, 99, 100, -1]).tolist() == [True, False, True, False, False]
    assert 31 in table and 32 not in table and "31" not in table
    # replaced by a part of other group ids: it leaves its block for another
    five = _part(rng, "physics", 5, holes=False)
    table.put(31, five)
    assert len(table) == 6
    top, _ = table.stacked([31])
    assert np.array_equal(top[0], five.top)
    with np.testing.assert_raises(ValueError):  # two blocks
        table.stacked([31, 50])
    table.drop_many([50, 1000, 3, 50])  # an unknown id and a repeated one are skipped
    assert len(table) == 4 and table.contains([50, 3]).tolist() == [False, False]
    with np.testing.assert_raises(KeyError):
        table.stacked([7, 50])
    order = [99, 7, 12]  # any order comes back in that order
    top, bottom = table.stacked(order)
    assert np.array_equal(top, np.stack([six[s].top for s in order]))
    assert np.array_equal(bottom, np.stack([six[s].bottom for s in order]))
    assert table.seeds([12, 31, 99]).tolist() == [six[12].seed, five.seed, six[99].seed]
    table.drop(31)  # its block is empty now, and made again by the next part of those ids
    again = _part(rng, "physics", 5, holes=True)
    table.put(8, again)
    metric, stable = table.intervals_of([8, 7])
    assert np.array_equal(metric[0], again.metric_ci, equal_nan=True)
    assert tuple(stable[1]) == six[7].stable_ci


def test_an_id_index_maps_ids_in_any_order_and_skips_unknown_ones() -> None:
    index = IdIndex()
    index.add([40, 7, 19], [0, 1, 2])
    index.add([3], [9])
    assert index.ids.tolist() == [3, 7, 19, 40] and len(index) == 4
    assert index.get([19, 5, 40, 3, 100]).tolist() == [2, -1, 0, 9, -1]
    assert index.contains([7, 8]).tolist() == [True, False]
    assert sorted(index.remove([7, 8, 40, 7]).tolist()) == [0, 1]  # unknown and repeated ids skipped
    assert index.get([3, 7, 19, 40]).tolist() == [9, -1, 2, -1]
    assert index.remove([]).tolist() == [] and len(index) == 2
