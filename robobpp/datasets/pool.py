"""The box pools of each dataset split, loaded from the verified cache (fetched on first use).

A pool is the sequence the sampling rule draws from: for ``repetitive`` the boxes of the split's records
in time order, each record of pick quantity q expanded to q identical consecutive boxes; for ``diverse``
one entry per usable SKU with its shipment proportion as weight; for ``longboard`` one entry per panel.

Entries that fit the container in no allowed orientation (9 Long Board panels longer than the container) are
left out of every pool and counted in ``notes["unplaceable"]``: such a box ends any episode it is drawn into, for
every method, and the reference evaluation cannot place them either.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from robobpp.core import Box
from robobpp.datasets.cache import converted_dir, data_dir, read_manifest, verify_converted
from robobpp.datasets.importer import SPLIT_CODES, Notify, fetch, fits_container
from robobpp.datasets.registry import check_split

_arrays: dict[tuple[str, int, int], dict[str, np.ndarray]] = {}


def _rich_notify() -> Notify:
    """Progress lines on stderr, so a first use inside a command that prints JSON keeps stdout clean."""
    from rich.console import Console

    console = Console(stderr=True)
    return lambda msg: console.print(f"[bold cyan]robobpp datasets[/]: {msg}", highlight=False)


def ensure_cache(root: Path | None = None, notify: Notify | None = None) -> Path:
    """The converted directory; fetches (with a progress message) when it does not exist yet.

    An existing but corrupted cache is *not* silently rebuilt: loading reports it (see ``verify_converted``).
    """
    root = root or data_dir()
    directory = converted_dir(root)
    if read_manifest(directory) is None:
        say = notify or _rich_notify()
        say(f"RoboBPP data not found in {root}; fetching it once (packsim 0.0.4 wheel, ~42 MB)")
        fetch(root, notify=say)
    return directory


def load_records(dataset: str, root: Path | None = None) -> dict[str, np.ndarray]:
    """All converted records of a dataset (every split), checked against the manifest. Read-only arrays."""
    check_split(dataset, "train")
    directory = ensure_cache(root)
    manifest = read_manifest(directory)
    assert manifest is not None
    path = verify_converted(directory, manifest, f"{dataset}.npz")
    stat = path.stat()
    key = (str(path), stat.st_mtime_ns, stat.st_size)
    if key not in _arrays:
        with np.load(path, allow_pickle=False) as npz:
            loaded = {name: npz[name] for name in npz.files}
        for array in loaded.values():
            array.setflags(write=False)
        _arrays[key] = loaded
    return _arrays[key]


@dataclass(frozen=True)
class Pool:
    dataset: str
    split: str
    #: (n, 3) length ≥ width, height per pool entry, cm.
    dims: np.ndarray
    #: (n,) kg.
    masses: np.ndarray
    #: (n,) sampling weights summing to 1 (diverse), or None.
    weights: np.ndarray | None
    #: (n,) index into the split's records of each entry (repetitive: several boxes share a record).
    record_index: np.ndarray
    #: Source records in the split.
    records: int
    notes: dict[str, int] = field(default_factory=dict)
    #: One Box per distinct (length, width, height, mass), made when first drawn: a Box is immutable, and a group
    #: repeats few sizes (a Gym env draws a group at every reset).
    _boxes: dict[tuple[float, float, float, float], Box] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    def __len__(self) -> int:
        return len(self.dims)

    def boxes(self, indices: np.ndarray) -> tuple[Box, ...]:
        made = self._boxes
        out = []
        # tolist: the same Python floats as float() of each element, without a numpy scalar per value
        for (length, width, height), mass in zip(
            self.dims[indices].tolist(), self.masses[indices].tolist(), strict=True
        ):
            key = (length, width, height, mass)
            box = made.get(key)
            if box is None:
                box = made[key] = Box(length, width, height, mass)
            out.append(box)
        return tuple(out)


def load_pool(
    dataset: str, split: str = "train", *, density_kg_m3: float | None = None, root: Path | None = None
) -> Pool:
    """The pool of one split. ``density_kg_m3`` overrides the registry's assumed density (no-mass datasets)."""
    spec = check_split(dataset, split)
    rec = load_records(dataset, root)
    mask = rec["split"] == SPLIT_CODES[split]
    dims = np.stack([rec["length"][mask], rec["width"][mask], rec["height"][mask]], axis=1)
    records = int(mask.sum())
    notes: dict[str, int] = {}
    weights = None
    if dataset == "repetitive":
        quantity = rec["quantity"][mask]
        record_index = np.repeat(np.arange(records), quantity)
        dims = dims[record_index]
        masses = rec["mass"][mask][record_index]
        notes["duplicate_records"] = int(rec["duplicate"][mask].sum())
    else:
        density = density_kg_m3 if density_kg_m3 is not None else spec.density_kg_m3
        if density is None or not np.isfinite(density) or density <= 0:
            raise ValueError(f"density for {dataset} must be a finite number > 0, got {density!r}")
        record_index = np.arange(records)
        masses = dims.prod(axis=1) * 1e-6 * density
        if dataset == "diverse":
            proportion = rec["proportion"][mask]
            weights = proportion / proportion.sum()
    fits = fits_container(dims, spec.container)
    notes["unplaceable"] = int((~fits).sum())
    if not fits.all():
        dims, masses, record_index = dims[fits], masses[fits], record_index[fits]
        if weights is not None:
            weights = weights[fits] / weights[fits].sum()
    return Pool(dataset, split, dims, masses, weights, record_index, records, notes)
