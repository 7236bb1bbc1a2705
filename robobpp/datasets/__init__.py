"""The RoboBPP datasets: registry, importer of the packsim wheel's files, splits, sampling, synthetic data.

Real data is fetched and converted on first use (``robobpp datasets fetch`` does it explicitly); see
docs/datasets.md for the sources, the facts the importer handles, the conventions and the cache layout.
"""

from robobpp.datasets.errors import (
    CacheCorruptError,
    ChecksumError,
    DatasetError,
    FetchError,
    SourceFormatError,
    SpecFileError,
)
from robobpp.datasets.importer import fetch
from robobpp.datasets.pool import Pool, load_pool, load_records
from robobpp.datasets.private import build_private, load_private
from robobpp.datasets.registry import (
    DATASETS,
    EVAL_GROUPS,
    GROUP_SIZE,
    SPLITS,
    DatasetSpec,
    UnknownDatasetError,
    UnknownSplitError,
    get_dataset,
)
from robobpp.datasets.sampling import episode_specs, group_seed

__all__ = [
    "DATASETS",
    "EVAL_GROUPS",
    "GROUP_SIZE",
    "SPLITS",
    "CacheCorruptError",
    "ChecksumError",
    "DatasetError",
    "DatasetSpec",
    "FetchError",
    "Pool",
    "SourceFormatError",
    "SpecFileError",
    "UnknownDatasetError",
    "UnknownSplitError",
    "build_private",
    "episode_specs",
    "fetch",
    "get_dataset",
    "group_seed",
    "load_pool",
    "load_private",
    "load_records",
]
