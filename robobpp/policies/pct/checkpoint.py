"""PCT's trained weights: read from the packsim wheel in the datasets cache, hash-checked, no code executed.

The authors ship the weights as ``packsim/packer/pct.pt`` inside the ``packsim==0.0.4`` wheel our datasets
importer already downloads and verifies. A ``.pt`` file is a zip archive: ``<folder>/data.pkl`` (a pickle
that names tensor-rebuild functions and storage records) beside one raw little-endian file per storage
(``<folder>/data/<key>``). Unpickling it with :mod:`pickle` would import and call whatever the pickle names,
so :class:`_TensorUnpickler` resolves only the handful of names a state dict uses, to our own numpy
functions, and refuses everything else. PyTorch is never imported.
"""

from __future__ import annotations

import functools
import io
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from robobpp.datasets.sources import WHEEL_NAME, sha256_bytes

#: The member of the wheel that holds the weights, and its sha256 (the file dated 2024-11-21, 238,250 bytes).
MEMBER = "packsim/packer/pct.pt"
PCT_SHA256 = "d4fc06207027a040b8694cd603cd167b266f12775edb0745f85b1fae1096db87"

#: torch storage class name → numpy dtype of its raw bytes (little-endian, as torch writes them).
_STORAGE_DTYPES: dict[str, str] = {
    "FloatStorage": "<f4",
    "DoubleStorage": "<f8",
    "HalfStorage": "<f2",
    "LongStorage": "<i8",
    "IntStorage": "<i4",
    "ShortStorage": "<i2",
    "CharStorage": "i1",
    "ByteStorage": "u1",
    "BoolStorage": "?",
}


class CheckpointError(ValueError):
    """The weights file is missing, altered, or not a plain tensor state dict."""


def _rebuild_tensor(
    storage: np.ndarray, offset: int, size: tuple[int, ...], stride: tuple[int, ...], *_rest: Any
) -> np.ndarray:
    """numpy twin of ``torch._utils._rebuild_tensor_v2``: a strided view, copied so it owns its memory."""
    item = storage.itemsize
    if not size:
        return np.array(storage[offset])
    needed = offset + sum((n - 1) * s for n, s in zip(size, stride, strict=True)) + 1
    if offset < 0 or needed > storage.size or any(s < 0 for s in stride):
        raise CheckpointError(
            f"tensor view {size}/{stride}+{offset} lies outside its storage of {storage.size}"
        )
    view = np.lib.stride_tricks.as_strided(
        storage[offset:], shape=tuple(size), strides=tuple(s * item for s in stride), writeable=False
    )
    return np.array(view)


class _StateDict(dict[str, Any]):
    """Stands in for ``collections.OrderedDict``; a dict subclass so the pickle may set ``_metadata`` on it."""


class _TensorUnpickler(pickle.Unpickler):
    """Unpickles a torch state dict into ``{name: ndarray}``; any other global is an error."""

    _ALLOWED = {
        ("collections", "OrderedDict"): _StateDict,
        ("torch._utils", "_rebuild_tensor_v2"): _rebuild_tensor,
        ("torch._utils", "_rebuild_tensor"): _rebuild_tensor,
    }

    def __init__(self, data: bytes, archive: zipfile.ZipFile, folder: str) -> None:
        super().__init__(io.BytesIO(data))
        self._archive = archive
        self._folder = folder

    def find_class(self, module: str, name: str) -> Any:
        found = self._ALLOWED.get((module, name))
        if found is not None:
            return found
        if module == "torch" and name in _STORAGE_DTYPES:
            return name  # a storage class is only a tag: its name selects the dtype
        raise CheckpointError(f"refusing to load {module}.{name}: a weights file holds tensors only")

    def persistent_load(self, pid: Any) -> np.ndarray:
        # ('storage', storage_type, key, location, numel): the raw bytes are the zip member data/<key>
        if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage"):
            raise CheckpointError(f"unexpected persistent id {pid!r} in the weights file")
        _, kind, key, _location, numel = pid
        if kind not in _STORAGE_DTYPES or not isinstance(key, str) or not key.isdigit():
            raise CheckpointError(f"unexpected storage record {pid!r} in the weights file")
        raw = self._archive.read(f"{self._folder}/data/{key}")
        array = np.frombuffer(raw, dtype=_STORAGE_DTYPES[kind])
        if array.size != numel:
            raise CheckpointError(f"storage {key}: {array.size} values, the pickle says {numel}")
        return array


def read_state_dict(data: bytes) -> dict[str, np.ndarray]:
    """Parse the bytes of a torch zip checkpoint holding a plain state dict into float32 numpy arrays."""
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except zipfile.BadZipFile as exc:
        raise CheckpointError(f"not a zip-format torch checkpoint ({exc})") from exc
    with archive:
        pickles = [n for n in archive.namelist() if n.endswith("/data.pkl")]
        if len(pickles) != 1:
            raise CheckpointError(f"expected one <folder>/data.pkl in the checkpoint, found {len(pickles)}")
        folder = pickles[0][: -len("/data.pkl")]
        try:
            state = _TensorUnpickler(archive.read(pickles[0]), archive, folder).load()
        except CheckpointError:
            raise
        except (pickle.UnpicklingError, EOFError, KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(f"unreadable weights pickle ({exc})") from exc
    if isinstance(state, tuple) and len(state) == 2:  # some PCT checkpoints are (state_dict, ob_rms)
        state = state[0]
    if not isinstance(state, dict) or not all(
        isinstance(k, str) and isinstance(v, np.ndarray) for k, v in state.items()
    ):
        raise CheckpointError("the checkpoint is not a mapping of names to tensors")
    return {k: v.astype(np.float32) for k, v in state.items()}


def read_weights_bytes(wheel: Path) -> bytes:
    """The weights file's bytes from the packsim wheel, checked against the pinned sha256."""
    try:
        with zipfile.ZipFile(wheel) as archive:
            data = archive.read(MEMBER)
    except KeyError as exc:
        raise CheckpointError(f"{wheel.name} has no {MEMBER}") from exc
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise CheckpointError(f"{wheel}: unreadable ({exc}); run `robobpp datasets fetch --force`") from exc
    actual = sha256_bytes(data)
    if actual != PCT_SHA256:
        raise CheckpointError(
            f"{MEMBER} in {wheel.name}: sha256 mismatch (size {len(data)} bytes): expected {PCT_SHA256}, "
            f"got {actual}; run `robobpp datasets fetch --force`"
        )
    return data


def cached_wheel() -> Path:
    """The verified packsim wheel of the datasets cache, fetched (download + verify) on first use."""
    from robobpp.datasets.cache import wheels_dir

    wheel = wheels_dir() / WHEEL_NAME
    if not wheel.is_file():
        from robobpp.datasets import fetch

        fetch()
    return wheel


@functools.lru_cache(maxsize=2)
def load_weights(wheel: Path | None = None) -> dict[str, np.ndarray]:
    """The PCT state dict (name → float32 array) from the cached wheel; memoised per process."""
    return read_state_dict(read_weights_bytes(wheel or cached_wheel()))
