"""The importer on the real packsim wheel: counts, splits, flags and conventions of docs/datasets.md."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from robobpp.datasets import DATASETS, load_pool, load_records
from robobpp.datasets.cache import MANIFEST, converted_dir
from robobpp.datasets.importer import diverse_is_test, fits_container
from robobpp.datasets.sources import SOURCE_SHA256

pytestmark = pytest.mark.network

# First 12 hex digits of each source's sha256 (docs/datasets.md, "Source and integrity", lists them in full).
BENCHMARK_PREFIXES = {
    "pg.xlsx": "548c9e36bd37",
    "pg_train.xlsx": "d3794e285dc0",
    "pg_test.xlsx": "dd42c3545021",
    "deli.xlsx": "24dac6b6d83e",
    "opai.txt": "53e67b23d513",
    "opai_train.txt": "c92cc06faf07",
    "opai_test.txt": "50c5dc206319",
}


def _manifest(root: Path) -> dict:
    return json.loads((converted_dir(root) / MANIFEST).read_text())


def test_full_source_hashes_extend_the_benchmark_prefixes() -> None:
    by_name = {Path(k).name: v for k, v in SOURCE_SHA256.items()}
    assert set(by_name) == set(BENCHMARK_PREFIXES)
    for name, prefix in BENCHMARK_PREFIXES.items():
        assert by_name[name].startswith(prefix) and len(by_name[name]) == 64


def test_record_counts_match_the_paper(real_data: Path) -> None:
    facts = _manifest(real_data)["datasets"]
    assert facts["repetitive"]["records"] == 16_767
    assert facts["diverse"]["records"] == 6_849
    assert facts["diverse"]["zero_rows_excluded"] == 48
    assert facts["diverse"]["usable"] == 6_801
    assert facts["longboard"]["records"] == 293
    assert len(load_records("repetitive")["record_id"]) == 16_767
    assert len(load_records("diverse")["code"]) == 6_801
    assert len(load_records("longboard")["length"]) == 293


def test_cache_is_complete_and_has_no_leftovers(real_data: Path) -> None:
    manifest = _manifest(real_data)
    assert set(manifest["files"]) == {"repetitive.npz", "diverse.npz", "longboard.npz"}
    assert manifest["source"]["sha256"] == "767e2d1704e5f0117ccdf5c52952733ed421cad24b8e0af95b5f2876fcab76be"
    assert not [p.name for p in real_data.iterdir() if p.name.startswith(".packsim")]
    assert sorted(p.name for p in converted_dir(real_data).iterdir()) == sorted(
        [MANIFEST, *manifest["files"]]
    )


def test_repetitive_split_is_time_ordered_earliest_fifth_for_test(real_data: Path) -> None:
    rec = load_records("repetitive")
    starts = rec["start_time"]
    assert list(starts) == sorted(starts)
    test, train = rec["split"] == 1, rec["split"] == 0
    assert test.sum() == 3_353 and train.sum() == 13_414
    assert np.flatnonzero(test).max() < np.flatnonzero(train).min()  # test = the first rows
    assert max(starts[test]) <= min(starts[train])


def test_repetitive_duplicates_are_kept_and_flagged(real_data: Path) -> None:
    rec = load_records("repetitive")
    flagged = np.flatnonzero(rec["duplicate"])
    assert len(flagged) == 58
    for i in flagged:
        assert rec["start_time"][i] == rec["start_time"][i - 1]
        assert rec["material"][i] == rec["material"][i - 1]
        assert rec["quantity"][i] == rec["quantity"][i - 1]
        assert rec["record_id"][i] != rec["record_id"][i - 1]


def test_repetitive_quantities_masses_and_expansion(real_data: Path) -> None:
    rec = load_records("repetitive")
    assert rec["quantity"].min() == 1 and rec["quantity"].max() == 16
    assert rec["mass"].min() == pytest.approx(0.522) and rec["mass"].max() == pytest.approx(10.597)
    pool = load_pool("repetitive", "test")
    quantity = rec["quantity"][rec["split"] == 1]
    assert len(pool) == int(quantity.sum())
    # Record r yields quantity[r] identical consecutive boxes carrying its gross weight.
    assert np.array_equal(np.bincount(pool.record_index), quantity)
    assert np.all(np.diff(pool.record_index) >= 0)
    assert np.array_equal(pool.masses, rec["mass"][rec["split"] == 1][pool.record_index])


def test_dims_convention_length_is_the_longer_side(real_data: Path) -> None:
    for name in ("repetitive", "diverse", "longboard"):
        rec = load_records(name)
        assert np.all(rec["length"] >= rec["width"])
        np.testing.assert_array_equal(rec["length"], np.maximum(rec["raw_length"], rec["raw_width"]))
    diverse = load_records("diverse")
    # Facts of the source: the W column is the longest side in ~96 % of SKUs.
    assert _manifest(real_data)["datasets"]["diverse"]["w_column_longest_share"] == pytest.approx(
        0.959, abs=0.002
    )
    assert (diverse["raw_width"] == diverse["length"]).mean() > 0.99


def test_diverse_split_by_stable_hash_and_weights(real_data: Path) -> None:
    rec = load_records("diverse")
    expected = np.asarray([diverse_is_test(str(c)) for c in rec["code"]])
    assert np.array_equal(rec["split"] == 1, expected)
    share = expected.mean()
    assert 0.18 < share < 0.22
    for split in ("train", "test"):
        pool = load_pool("diverse", split)
        assert pool.weights is not None and pool.weights.sum() == pytest.approx(1.0)
        volumes = pool.dims.prod(axis=1)
        np.testing.assert_allclose(pool.masses, volumes * 1e-6 * 250.0)


def test_longboard_pools_leave_out_the_unplaceable_panels(real_data: Path) -> None:
    facts = _manifest(real_data)["datasets"]["longboard"]
    assert facts["unplaceable"] == 9 and facts["train"] == 234 and facts["test"] == 59
    pools = [load_pool("longboard", s) for s in ("train", "test")]
    assert [p.notes["unplaceable"] for p in pools] == [7, 2]
    assert [len(p) for p in pools] == [227, 57] and [p.records for p in pools] == [234, 59]
    dims = np.vstack([p.dims for p in pools])
    assert not any(tuple(d) == (660.0, 225.0, 8.0) for d in dims)  # the probable typo: fits nowhere, left out
    container = DATASETS["longboard"].container
    assert fits_container(dims, container).all()
    np.testing.assert_allclose(pools[0].masses, pools[0].dims.prod(axis=1) * 1e-6 * 400.0)
    heavier = load_pool("longboard", "train", density_kg_m3=800.0)
    np.testing.assert_allclose(heavier.masses, 2 * pools[0].masses)
