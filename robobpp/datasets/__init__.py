"""The RoboBPP datasets: registry, importer of the packsim wheel's files, splits, sampling, synthetic data."""

from robobpp.datasets.registry import (
    DATASETS,
    EVAL_GROUPS,
    GROUP_SIZE,
    SPLITS,
    DatasetSpec,
    UnknownDatasetError,
    get_dataset,
)

__all__ = ["DATASETS", "EVAL_GROUPS", "GROUP_SIZE", "SPLITS", "DatasetSpec", "UnknownDatasetError", "get_dataset"]
