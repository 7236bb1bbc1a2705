"""The private evaluation set: 30 test-pool groups per dataset, written as files the loader validates."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from robobpp.datasets import DATASETS, SpecFileError, build_private, episode_specs, load_private
from robobpp.datasets.private import stale_datasets
from robobpp.datasets.sampling import SAMPLER_VERSION
from robobpp.datasets.sources import sha256_file

pytestmark = pytest.mark.network


def test_build_and_load_round_trip(real_data: Path, tmp_path: Path) -> None:
    root = tmp_path / "private"
    written = build_private(root, seed=1234)
    assert set(written) == set(DATASETS)
    for name in DATASETS:
        specs = load_private(name, root)
        assert len(specs) == 30 and all(len(s.boxes) == 80 for s in specs)
        assert specs == episode_specs(name, "test", groups=30, seed=1234)
        assert {s.split for s in specs} == {"test"}
    manifest = json.loads((root / "manifest.json").read_text())
    assert "1234" not in json.dumps(manifest)  # the seed is not written down


def test_secret_seed_differs_between_builds(real_data: Path, tmp_path: Path) -> None:
    build_private(tmp_path / "a", groups=2, datasets=["longboard"])
    build_private(tmp_path / "b", groups=2, datasets=["longboard"])
    assert load_private("longboard", tmp_path / "a") != load_private("longboard", tmp_path / "b")


def test_altered_missing_or_absent_private_files(real_data: Path, tmp_path: Path) -> None:
    root = tmp_path / "private"
    build_private(root, seed=7, groups=2, datasets=["diverse", "longboard"])
    path = root / "diverse.json"
    doc = json.loads(path.read_text())
    doc["groups"][0]["boxes"][0][0] += 1
    path.write_text(json.dumps(doc))
    with pytest.raises(SpecFileError, match=r"diverse\.json: sha256 mismatch"):
        load_private("diverse", root)
    (root / "longboard.json").unlink()
    with pytest.raises(SpecFileError, match=r"longboard\.json: missing"):
        load_private("longboard", root)
    with pytest.raises(SpecFileError, match="no entry for repetitive"):
        load_private("repetitive", root)
    with pytest.raises(SpecFileError, match="build-private"):
        load_private("diverse", tmp_path / "empty")


def test_building_one_dataset_keeps_the_others(real_data: Path, tmp_path: Path) -> None:
    root = tmp_path / "private"
    build_private(root, seed=1, groups=2, datasets=["diverse"])
    build_private(root, seed=2, groups=3, datasets=["longboard"])
    assert len(load_private("diverse", root)) == 2 and len(load_private("longboard", root)) == 3


def test_the_manifest_records_the_sampler_and_a_set_of_another_version_is_refused(
    real_data: Path, tmp_path: Path
) -> None:
    root = tmp_path / "private"
    build_private(root, seed=3, groups=2, datasets=["repetitive"])
    path = root / "manifest.json"
    manifest = json.loads(path.read_text())
    assert manifest["datasets"]["repetitive"]["sampler"] == SAMPLER_VERSION
    assert stale_datasets(root, ["repetitive", "diverse"]) == ["diverse"]  # diverse: not built
    # A set built before entries recorded their sampler was drawn by version 1 (windows of the public pool).
    del manifest["datasets"]["repetitive"]["sampler"]
    path.write_text(json.dumps(manifest))
    with pytest.raises(SpecFileError, match=r"repetitive was drawn by sampler version 1.*build-private"):
        load_private("repetitive", root)
    assert stale_datasets(root, ["repetitive"]) == ["repetitive"]
    # A file of another version under a manifest that claims the current one is refused too.
    build_private(root, seed=3, groups=2, datasets=["repetitive"])
    doc = json.loads((root / "repetitive.json").read_text())
    doc["sampler"] = "1"
    (root / "repetitive.json").write_text(json.dumps(doc))
    manifest = json.loads(path.read_text())
    manifest["datasets"]["repetitive"]["sha256"] = sha256_file(root / "repetitive.json")
    path.write_text(json.dumps(manifest))
    with pytest.raises(SpecFileError, match=r"drawn by sampler version 1, not " + SAMPLER_VERSION):
        load_private("repetitive", root)
    assert stale_datasets(tmp_path / "nothing", ["longboard"]) == ["longboard"]
