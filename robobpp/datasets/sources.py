"""Where the RoboBPP data comes from: the pinned ``packsim==0.0.4`` wheel and the files inside it.

The raw company records are not committed to the repository; the wheel is fetched from the package index
with pip and every byte we read is checked against the hashes below before our own readers touch it.
"""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from robobpp.datasets.errors import ChecksumError, FetchError

PACKSIM_REQUIREMENT = "packsim==0.0.4"
WHEEL_NAME = "packsim-0.0.4-py3-none-any.whl"
WHEEL_SHA256 = "767e2d1704e5f0117ccdf5c52952733ed421cad24b8e0af95b5f2876fcab76be"

#: Full sha256 of each data file we read (docs/datasets.md, "Source and integrity", lists them).
SOURCE_SHA256: dict[str, str] = {
    "packsim/data/time_series/pg.xlsx": "548c9e36bd37b6e464470059a692c1317dbbb30d012594b708b0d770d15570d7",
    "packsim/data/time_series/pg_train.xlsx": "d3794e285dc04ebed4b4a8f0757be84ae153b5621a86d95897867a2069ad68eb",
    "packsim/data/time_series/pg_test.xlsx": "dd42c3545021e88071cc566703e3ddd03ed1955c3d65659451f6e461a720188a",
    "packsim/data/occupancy/deli.xlsx": "24dac6b6d83e31182c05a7e950d8cae93a897137052e9b097118dd42b271a9d5",
    "packsim/data/flat_long/opai.txt": "53e67b23d513f9d11b78b448842a7dcfe828788864488a6d106df1a7f6fd1377",
    "packsim/data/flat_long/opai_train.txt": "c92cc06faf07af6e038a80e4d846503b606398b5b3c4a6c58cbfec81242443b0",
    "packsim/data/flat_long/opai_test.txt": "50c5dc206319562b8442133576db9cdf52f560f119f47ee7da20af2f595c778d",
}


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def verify_wheel(path: Path, expected: str = WHEEL_SHA256) -> None:
    """Refuse a wheel whose sha256 is not the pinned one (truncated download, another build, tampering)."""
    if not path.is_file():
        raise FetchError(f"{path}: wheel file not found")
    actual = sha256_file(path)
    if actual != expected:
        raise ChecksumError(
            f"{path.name}: sha256 mismatch (size {path.stat().st_size} bytes): expected {expected}, got {actual}. "
            f"The file is truncated or altered; delete it and run `robobpp datasets fetch --force`."
        )


def verify_source(name: str, data: bytes | None, wheel: Path) -> bytes:
    """Check one data file read from the wheel against its pinned hash; returns the bytes for parsing."""
    expected = SOURCE_SHA256[name]
    if data is None:
        raise ChecksumError(f"{name}: missing from {wheel.name}; expected a file with sha256 {expected}")
    actual = sha256_bytes(data)
    if actual != expected:
        raise ChecksumError(
            f"{name} in {wheel.name}: sha256 mismatch (size {len(data)} bytes): expected {expected}, got {actual}"
            " (truncated or altered)"
        )
    return data


def download_wheel(dest_dir: Path) -> Path:
    """Download the pinned wheel with pip into a private temp dir, then move it to ``dest_dir``.

    The wheel is verified before it is moved, so ``dest_dir`` never holds a partial or wrong file.
    """
    dest_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".download-", dir=dest_dir) as tmp:
        cmd = [
            sys.executable,
            "-m",
            "pip",
            "download",
            "--no-deps",
            "--disable-pip-version-check",
            "--progress-bar",
            "off",
            PACKSIM_REQUIREMENT,
            "-d",
            tmp,
        ]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900, check=False)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise FetchError(f"could not run pip to download {PACKSIM_REQUIREMENT}: {exc}") from exc
        wheel = Path(tmp) / WHEEL_NAME
        if proc.returncode != 0 or not wheel.is_file():
            tail = "\n".join((proc.stderr or proc.stdout).strip().splitlines()[-5:])
            raise FetchError(
                f"`pip download --no-deps {PACKSIM_REQUIREMENT}` failed (exit {proc.returncode}); "
                f"the package index must be reachable.\n{tail}"
            )
        verify_wheel(wheel)
        target = dest_dir / WHEEL_NAME
        shutil.move(str(wheel), str(target.with_suffix(".partial")))
        target.with_suffix(".partial").replace(target)
    return target
