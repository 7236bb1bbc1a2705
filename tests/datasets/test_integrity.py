"""Bad input to the importer and a damaged cache: clear errors naming the file, nothing half-written."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import pytest

from robobpp.datasets import CacheCorruptError, ChecksumError, FetchError, episode_specs, fetch, load_pool
from robobpp.datasets.cache import MANIFEST, converted_dir
from robobpp.datasets.sources import SOURCE_SHA256, WHEEL_NAME, WHEEL_SHA256

pytestmark = pytest.mark.network


def _leftovers(root: Path) -> list[str]:
    return (
        [p.name for p in root.iterdir() if p.name.startswith(".") and p.name != ".lock"]
        if root.exists()
        else []
    )


def _rebuild(
    wheel: Path, out: Path, *, drop: str | None = None, alter: str | None = None, cut: str | None = None
) -> Path:
    """A small archive holding only the wheel's data files, one of them dropped, altered or truncated."""
    with zipfile.ZipFile(wheel) as src, zipfile.ZipFile(out, "w") as dst:
        for name in SOURCE_SHA256:
            if name == drop:
                continue
            data = src.read(name)
            if name == alter:
                data = data[:100] + bytes([data[100] ^ 0xFF]) + data[101:]
            if name == cut:
                data = data[: len(data) // 2]
            dst.writestr(name, data)
    return out


def test_wheel_with_wrong_checksum_is_refused(real_wheel: Path, tmp_path: Path) -> None:
    altered = tmp_path / WHEEL_NAME
    data = bytearray(real_wheel.read_bytes())
    data[len(data) // 2] ^= 0x01
    altered.write_bytes(bytes(data))
    root = tmp_path / "cache"
    with pytest.raises(ChecksumError) as err:
        fetch(root, wheel=altered)
    message = str(err.value)
    assert WHEEL_NAME in message and WHEEL_SHA256 in message and "expected" in message
    assert not converted_dir(root).exists() and not _leftovers(root)


def test_truncated_wheel_is_refused(real_wheel: Path, tmp_path: Path) -> None:
    cut = tmp_path / WHEEL_NAME
    cut.write_bytes(real_wheel.read_bytes()[:1_000_000])
    with pytest.raises(ChecksumError, match="sha256 mismatch"):
        fetch(tmp_path / "cache", wheel=cut)
    assert not converted_dir(tmp_path / "cache").exists()


def test_missing_wheel_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(FetchError, match="not found"):
        fetch(tmp_path / "cache", wheel=tmp_path / "nope.whl")


@pytest.mark.parametrize(
    ("mode", "name"),
    [
        ("drop", "packsim/data/flat_long/opai.txt"),
        ("alter", "packsim/data/time_series/pg.xlsx"),
        ("cut", "packsim/data/occupancy/deli.xlsx"),
    ],
)
def test_missing_altered_or_truncated_data_file(
    real_wheel: Path, tmp_path: Path, mode: str, name: str
) -> None:
    archive = _rebuild(real_wheel, tmp_path / "rebuilt.whl", **{mode: name})
    root = tmp_path / "cache"
    with pytest.raises(ChecksumError) as err:
        fetch(root, wheel=archive, wheel_sha256=None)  # skip the whole-wheel hash; per-file hashes apply
    message = str(err.value)
    assert name in message and SOURCE_SHA256[name] in message
    assert ("missing" in message) if mode == "drop" else ("sha256 mismatch" in message)
    assert not converted_dir(root).exists() and not _leftovers(root)


def test_failed_import_leaves_a_valid_cache_untouched(
    cache_copy: Path, real_wheel: Path, tmp_path: Path
) -> None:
    before = (converted_dir(cache_copy) / MANIFEST).read_text()
    archive = _rebuild(real_wheel, tmp_path / "rebuilt.whl", alter="packsim/data/flat_long/opai_test.txt")
    with pytest.raises(ChecksumError, match="opai_test.txt"):
        fetch(cache_copy, wheel=archive, wheel_sha256=None, force=True)
    assert (converted_dir(cache_copy) / MANIFEST).read_text() == before
    assert load_pool("longboard", "test").records == 59


def test_altered_converted_file_is_detected_at_load(cache_copy: Path) -> None:
    path = converted_dir(cache_copy) / "diverse.npz"
    data = bytearray(path.read_bytes())
    data[-10] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(CacheCorruptError) as err:
        episode_specs("diverse", "train", groups=1)
    assert "diverse.npz" in str(err.value) and "robobpp datasets fetch" in str(err.value)
    # fetch notices the damage and rebuilds from the verified cached wheel (no network needed).
    fetch(cache_copy)
    assert len(episode_specs("diverse", "train", groups=1)[0].boxes) == 80


def test_missing_converted_file_and_broken_manifest(cache_copy: Path) -> None:
    (converted_dir(cache_copy) / "longboard.npz").unlink()
    with pytest.raises(CacheCorruptError, match=r"longboard\.npz: missing"):
        load_pool("longboard", "train")
    (converted_dir(cache_copy) / MANIFEST).write_text("{not json")
    with pytest.raises(CacheCorruptError, match="manifest"):
        load_pool("repetitive", "train")


def test_tampered_cached_wheel_is_refused_on_rebuild(cache_copy: Path) -> None:
    shutil.rmtree(converted_dir(cache_copy))
    wheel = cache_copy / "wheels" / WHEEL_NAME
    wheel.write_bytes(wheel.read_bytes()[:-1])
    with pytest.raises(ChecksumError, match=WHEEL_NAME):
        fetch(cache_copy)
    assert not converted_dir(cache_copy).exists()


def test_manifest_checksums_cover_the_converted_files(real_data: Path) -> None:
    from robobpp.datasets.sources import sha256_file

    manifest = json.loads((converted_dir(real_data) / MANIFEST).read_text())
    for filename, entry in manifest["files"].items():
        assert sha256_file(converted_dir(real_data) / filename) == entry["sha256"]
